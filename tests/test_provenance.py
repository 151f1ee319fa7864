"""Provenance: the facts of the process that trains a run, recorded in provenance.json at its start and at every
resume (ilcsan.runs.provenance), and the report's note when the runs of one cell differ in them."""

from __future__ import annotations

import json
import os
import platform
import shutil
import subprocess
from datetime import UTC, datetime
from pathlib import Path

import gymnasium
import mujoco
import pytest
import torch

import ilcsan
from ilcsan.runs import provenance
from ilcsan.runs.checkpoint import TrainingCheckpoints
from ilcsan.runs.directory import PROVENANCE, RunDirectory

needs_git = pytest.mark.skipif(shutil.which("git") is None, reason="git is not installed")


def run_git(folder: Path, *arguments: str) -> str:
    return subprocess.run(["git", "-C", str(folder), "-c", "user.name=test", "-c", "user.email=test@example.invalid",
                           *arguments], capture_output=True, text=True, check=True).stdout.strip()


# ------------------------------------------------------------------------------------------ the facts
def test_a_segment_records_this_process_and_the_runs_choices() -> None:
    before = datetime.now(UTC).replace(microsecond=0)
    segment = provenance.collect(1234, "bf16", "bf16", "cpu")
    after = datetime.now(UTC)
    assert segment["step"] == 1234 and (segment["matmul"], segment["matmul_path"], segment["device"]) == (
        "bf16", "bf16", "cpu")
    assert segment["ilcsan"] == ilcsan.__version__
    assert segment["python"] == platform.python_version()
    assert (segment["torch"], segment["gymnasium"], segment["mujoco"]) == (
        torch.__version__, gymnasium.__version__, mujoco.__version__)
    assert segment["cores"] == os.cpu_count() and segment["threads"] == torch.get_num_threads()
    assert before <= datetime.strptime(segment["started"], "%Y-%m-%dT%H:%M:%SZ").replace(tzinfo=UTC) <= after
    assert isinstance(segment["cpu"], str) and segment["cpu"]
    assert json.loads(json.dumps(segment)) == segment, "plain JSON values only"


def test_the_thread_count_is_torchs_when_collected() -> None:
    threads = torch.get_num_threads()
    try:
        torch.set_num_threads(2)
        assert provenance.collect(0, "float32", "aten")["threads"] == 2
        torch.set_num_threads(1)
        assert provenance.collect(0, "float32", "aten")["threads"] == 1
    finally:
        torch.set_num_threads(threads)


def test_the_cpu_model_is_cpuinfos_model_name_else_the_platforms(tmp_path: Path, monkeypatch) -> None:
    cpuinfo = tmp_path / "cpuinfo"
    cpuinfo.write_text("processor\t: 0\nvendor_id\t: AuthenticAMD\nmodel name\t: AMD EPYC 9R14 96-Core Processor\n"
                       "processor\t: 1\nmodel name\t: AMD EPYC 9R14 96-Core Processor\n")
    assert provenance.cpu_model(cpuinfo) == "AMD EPYC 9R14 96-Core Processor"
    monkeypatch.setattr(platform, "processor", lambda: "arm")
    assert provenance.cpu_model(tmp_path / "absent") == "arm"
    cpuinfo.write_text("processor\t: 0\nmodel name\t:\n")
    assert provenance.cpu_model(cpuinfo) == "arm"
    monkeypatch.setattr(platform, "processor", lambda: "")
    assert provenance.cpu_model(tmp_path / "absent") is None


def test_the_cpu_flags_are_those_that_decide_the_matmul_paths(tmp_path: Path) -> None:
    cpuinfo = tmp_path / "cpuinfo"
    cpuinfo.write_text("model name\t: Intel(R) Xeon(R) Processor\nflags\t\t: fpu avx2 avx512f avx512_bf16 amx_tile "
                       "amx_bf16 amx_int8\n")
    assert provenance.cpu_flags(cpuinfo) == ["avx2", "avx512f", "avx512_bf16", "amx_bf16"]
    cpuinfo.write_text("model name\t: AMD EPYC\nflags\t\t: fpu avx2 avx512f avx512_bf16\n")
    assert provenance.cpu_flags(cpuinfo) == ["avx2", "avx512f", "avx512_bf16"]
    assert provenance.cpu_flags(tmp_path / "absent") is None
    same_name = [[segment(cpu="Intel(R) Xeon(R) Processor") | {"cpu_flags": flags}]
                 for flags in (["avx512f", "amx_bf16"], ["avx512f"])]
    assert provenance.differences(same_name) == ("runs differ in CPU (Intel Xeon [avx512f amx_bf16] ×1, Intel Xeon "
                                                 "[avx512f] ×1)")


def test_a_library_that_is_not_installed_is_none() -> None:
    assert provenance.library_version("torch") == torch.__version__
    assert provenance.library_version("ilcsan-no-such-distribution") is None


@needs_git
def test_the_commit_is_this_checkouts_head_when_the_package_runs_from_it() -> None:
    package = Path(ilcsan.__file__).resolve().parent
    checkout = Path(__file__).resolve().parents[1]
    if checkout not in package.parents or not (checkout / ".git").exists():
        pytest.skip("ilcsan is not imported from this checkout")
    segment = provenance.collect(0, "float32", "aten")
    assert segment["commit"] == run_git(checkout, "rev-parse", "HEAD")
    assert len(segment["commit"]) == 40 and isinstance(segment["dirty"], bool)
    assert segment["dirty"] == bool(run_git(checkout, "status", "--porcelain", "--", str(package)))


@needs_git
def test_the_dirty_flag_follows_the_package_folders_files(tmp_path: Path) -> None:
    checkout, package = tmp_path / "checkout", tmp_path / "checkout" / "src" / "pkg"
    package.mkdir(parents=True)
    (package / "__init__.py").write_text("x = 1\n")
    (checkout / "README.md").write_text("docs\n")
    (checkout / ".gitignore").write_text("__pycache__/\n")
    run_git(checkout, "init", "-q")
    run_git(checkout, "add", ".")
    run_git(checkout, "commit", "-q", "-m", "first")
    head = run_git(checkout, "rev-parse", "HEAD")
    assert provenance.source_revision(package) == (head, False)
    (package / "__pycache__").mkdir()
    (package / "__pycache__" / "x.pyc").write_bytes(b"ignored")
    (checkout / "README.md").write_text("docs changed\n")
    assert provenance.source_revision(package) == (head, False), "ignored files and docs are not the package's code"
    (package / "__init__.py").write_text("x = 2\n")
    assert provenance.source_revision(package) == (head, True), "a changed tracked file"
    run_git(checkout, "checkout", "-q", "--", ".")
    assert provenance.source_revision(package) == (head, False)
    (package / "new_module.py").write_text("y = 1\n")
    assert provenance.source_revision(package) == (head, True), "a new module in the package"
    run_git(checkout, "add", ".")
    run_git(checkout, "commit", "-q", "-m", "second")
    second = run_git(checkout, "rev-parse", "HEAD")
    assert second != head and provenance.source_revision(package) == (second, False)


@needs_git
def test_no_commit_outside_a_checkout_of_the_package_or_without_git(tmp_path: Path, monkeypatch) -> None:
    alone = tmp_path / "site-packages" / "pkg"
    alone.mkdir(parents=True)
    (alone / "__init__.py").write_text("")
    assert provenance.source_revision(alone) == (None, None)
    checkout = tmp_path / "checkout"  # a virtualenv inside a checkout: the package is in it but not tracked
    installed = checkout / ".venv" / "pkg"
    installed.mkdir(parents=True)
    (installed / "__init__.py").write_text("")
    (checkout / ".gitignore").write_text(".venv/\n")
    run_git(checkout, "init", "-q")
    run_git(checkout, "add", ".")
    run_git(checkout, "commit", "-q", "-m", "first")
    assert provenance.source_revision(installed) == (None, None)
    tracked = checkout / "pkg"
    tracked.mkdir()
    (tracked / "__init__.py").write_text("")
    run_git(checkout, "add", ".")
    run_git(checkout, "commit", "-q", "-m", "second")
    assert provenance.source_revision(tracked)[0] == run_git(checkout, "rev-parse", "HEAD")
    monkeypatch.setenv("PATH", str(tmp_path / "no-programs"))
    assert provenance.source_revision(tracked) == (None, None)


# -------------------------------------------------------------------------------------- the segments
def test_a_new_segment_drops_those_that_began_at_or_after_its_step() -> None:
    first, second, crashed = ({"step": step, "cpu": name} for step, name in ((0, "a"), (150, "b"), (300, "c")))
    resumed = {"step": 300, "cpu": "d"}
    assert provenance.extend([first, second, crashed], resumed) == [first, second, resumed]
    assert provenance.extend([first, second], resumed) == [first, second, resumed]
    assert provenance.extend([first, second, crashed], {"step": 150, "cpu": "e"}) == [first, {"step": 150, "cpu": "e"}]
    restarted = {"step": 0, "cpu": "f"}
    assert provenance.extend([first, second], restarted) == [restarted], "a new run starts a new list"


def test_a_damaged_provenance_file_starts_again_with_a_line(tmp_path: Path) -> None:
    directory = RunDirectory(tmp_path / "run")
    directory.path.mkdir()
    directory.file(PROVENANCE).write_text('{"segments": [{"step": 0}')
    lines: list[str] = []
    segment = {"step": 150, "cpu": "x"}
    TrainingCheckpoints([directory], lines.append).record_provenance(segment)
    assert directory.provenance() == [segment]
    assert len(lines) == 1 and "provenance.json is damaged" in lines[0]
    TrainingCheckpoints([directory], lines.append).record_provenance({"step": 300, "cpu": "y"})
    assert directory.provenance() == [segment, {"step": 300, "cpu": "y"}] and len(lines) == 1


def test_a_run_records_a_segment_when_it_starts_and_another_when_it_resumes(tmp_path: Path, monkeypatch) -> None:
    """Two stacked seeds, interrupted after their first checkpoint (step 10) and resumed with ``--matmul bf16``: each
    seed's provenance.json keeps the first segment as it was and adds one at the checkpoint's step with the resumed
    run's precision (config.json keeps the path the run started on). The matmul measurement is replaced by a fixed
    choice (it takes a minute on a busy machine and is not what this test is about)."""
    import dataclasses

    from test_training import interrupt_after_first_checkpoint, tiny_run

    from ilcsan.compute.matmul import MatmulPath
    from ilcsan.rl import run_setup, training

    def choose(config, state_dim, action_dim, episode_steps=None):
        path = "bf16" if config.matmul == "bf16" else "aten"
        return MatmulPath(path, set() if path == "bf16" else None), {"path": path, "compiled": False, "gflops": {}}

    monkeypatch.setattr(run_setup, "choose_matmul_path", choose)
    config = tiny_run(seeds=(0, 1), steps=20, eval_every=10, actor=ilcsan.actor_config("ilc-san", hidden=(8,)))
    out = tmp_path / "run"
    interrupt_after_first_checkpoint(config, out, monkeypatch)
    folders = [RunDirectory(out / f"seed{seed}") for seed in config.seeds]
    started = [folder.provenance() for folder in folders]
    for folder, segments in zip(folders, started, strict=True):
        assert folder.checkpoint_step() == 10
        assert len(segments) == 1 and segments[0]["step"] == 0
        (segment,) = segments
        assert (segment["matmul"], segment["matmul_path"], segment["threads"], segment["device"]) == (
            "float32", "aten", 1, "cpu")
    assert started[0] == started[1], "the seeds of one process share its provenance"

    training.train(dataclasses.replace(config, matmul="bf16"), out, resume=True, progress=False, log=lambda *_: None)
    for folder, before in zip(folders, started, strict=True):
        segments = folder.provenance()
        assert [segment["step"] for segment in segments] == [0, 10]
        assert segments[0] == before[0], "a resumed run keeps its earlier segments as they were"
        assert (segments[1]["matmul"], segments[1]["matmul_path"]) == ("bf16", "bf16")
        assert folder.config_object()["matmul_path"]["path"] == "aten"
        assert folder.result()["steps_done"] == 20


# ---------------------------------------------------------------------------------------- the report
AMD, INTEL = "AMD EPYC 9R14 96-Core Processor", "Intel(R) Xeon(R) Platinum 8488C"


def segment(step: int = 0, cpu: str = AMD, commit: str = "a" * 40, dirty: bool = False, matmul: str = "float32",
            path: str = "aten", torch_version: str = "2.13.0+cpu") -> dict:
    """A segment as :func:`provenance.collect` writes it."""
    return {"step": step, "started": "2026-12-01T10:00:00Z", "ilcsan": "0.1.0", "commit": commit, "dirty": dirty,
            "python": "3.11.7", "torch": torch_version, "gymnasium": "1.4.0", "mujoco": "4.0.1", "cpu": cpu,
            "cores": 2, "threads": 1, "device": "cpu", "matmul": matmul, "matmul_path": path}


def intra_cell(root: Path, *runs: list[dict] | None) -> None:
    """One run per entry in Table intra's Hopper I_intra cell (written as test_report writes runs), each with those
    segments in its provenance.json (None: without one)."""
    from test_report import intra_run

    for seed, segments in enumerate(runs):
        folder = intra_run(root, "Hopper", "intra", seed, [1000.0 + seed, 2000.0])
        if segments is not None:
            (folder / PROVENANCE).write_text(json.dumps({"segments": segments}))


def report_notes(root: Path) -> tuple[list[str], str, str]:
    """The provenance lines of report.md (without their bullets) and the whole report.md and report.tex."""
    from ilcsan.analysis.report import write_report

    paths = write_report(root)
    markdown, latex = paths["markdown"].read_text(), paths["latex"].read_text()
    lines = markdown.splitlines()
    if "Provenance" not in markdown:
        return [], markdown, latex
    start = next(index for index, line in enumerate(lines) if line.startswith("Provenance ("))
    notes = []
    for line in lines[start + 2:]:
        if not line.startswith("- "):
            break
        notes.append(line[2:])
    return notes, markdown, latex


def test_the_report_says_which_aspects_set_the_runs_of_a_cell_apart(tmp_path: Path) -> None:
    b = "b" * 40
    intra_cell(tmp_path, [segment()], [segment()], [segment(cpu=INTEL)], [segment(cpu=INTEL, commit=b)])
    notes, markdown, latex = report_notes(tmp_path)
    expected = ("Hopper · I_intra: runs differ in CPU (AMD EPYC 9R14 96-Core ×2, Intel Xeon Platinum 8488C ×2) and "
                "code (aaaaaaa ×3, bbbbbbb ×1).")
    assert notes == [expected.replace("_", "\\_")]
    assert f"% {expected}" in latex.splitlines()


def test_precision_library_versions_and_dirty_code_are_differences_too_and_each_segment_counts(tmp_path: Path) -> None:
    resumed_elsewhere = [segment(), segment(step=200_000, cpu=INTEL, matmul="bf16", path="bf16")]
    intra_cell(tmp_path, [segment(path="onednn", dirty=True)], [segment(torch_version="2.12.0")], resumed_elsewhere)
    (note,) = report_notes(tmp_path)[0]
    assert note == ("Hopper · I\\_intra: runs differ in CPU (AMD EPYC 9R14 96-Core ×3, Intel Xeon Platinum 8488C ×1), "
                    "code (aaaaaaa ×2, aaaaaaa+dirty ×1), precision (float32 (aten) ×2, bf16 ×1, float32 (onednn) ×1) "
                    "and torch (2.13.0+cpu ×2, 2.12.0 ×1).")


def test_runs_that_agree_give_no_note_and_only_a_partly_recorded_cell_says_so(tmp_path: Path) -> None:
    same = [segment(), segment(step=150_000)]  # resumed on the same machine and code: nothing to say
    named = [segment(matmul="aten")]  # --matmul aten computes as a measured aten: the same precision
    intra_cell(tmp_path / "agree", same, [segment()], named)
    notes, markdown, _ = report_notes(tmp_path / "agree")
    assert notes == [] and "Provenance" not in markdown and "differ in" not in markdown
    intra_cell(tmp_path / "older", None, None)  # runs of a version before provenance.json: no noise either
    notes, markdown, _ = report_notes(tmp_path / "older")
    assert notes == [] and "Provenance" not in markdown and "not recorded" not in markdown
    intra_cell(tmp_path / "part", [segment()], None, [segment(cpu=INTEL)])
    assert report_notes(tmp_path / "part")[0] == [
        "Hopper · I\\_intra: runs differ in CPU (AMD EPYC 9R14 96-Core ×1, Intel Xeon Platinum 8488C ×1); "
        "provenance not recorded for 1 of 3 runs."]
    intra_cell(tmp_path / "part-same", [segment()], None)
    assert report_notes(tmp_path / "part-same")[0] == ["Hopper · I\\_intra: provenance not recorded for 1 of 2 runs."]


def test_a_damaged_provenance_file_counts_as_not_recorded_and_the_run_still_counts(tmp_path: Path) -> None:
    from ilcsan.analysis.collect import collect_runs

    intra_cell(tmp_path, [segment()], [segment()])
    (tmp_path / "intra" / "Hopper" / "intra" / "seed1" / PROVENANCE).write_text("{not json")
    runs = collect_runs(tmp_path)
    assert len(runs) == 2 and [run.provenance is None for run in runs] == [False, True]
    assert report_notes(tmp_path)[0] == ["Hopper · I\\_intra: provenance not recorded for 1 of 2 runs."]


def test_the_differences_of_one_cell_leave_the_other_cells_alone(tmp_path: Path) -> None:
    from test_report import intra_run

    intra_cell(tmp_path, [segment()], [segment(cpu=INTEL)])
    for seed in (0, 1):
        folder = intra_run(tmp_path, "Hopper", "none", seed, [900.0, 950.0])
        (folder / PROVENANCE).write_text(json.dumps({"segments": [segment(cpu=INTEL)]}))
    notes = report_notes(tmp_path)[0]
    assert len(notes) == 1 and notes[0].startswith("Hopper · I\\_intra: runs differ in CPU (")
