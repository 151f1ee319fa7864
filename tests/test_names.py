"""One meaning per name: no class name defined twice in the package, one constant per default name, the training
settings called ``training`` while the files and Python names written before (``td3``, ``TD3Config``) still read,
and a run recording only the settings its algorithm uses."""

from __future__ import annotations

import ast
import json
import shutil
import warnings
from collections import defaultdict
from pathlib import Path

import pytest

import ilcsan
from ilcsan import methods
from ilcsan.config import ActorConfig, RunConfig, TrainingConfig, training_config_class

PACKAGE = Path(ilcsan.__file__).parent
DOCS = Path(__file__).resolve().parents[1] / "docs"
TD3_RUN = DOCS / "paper-table" / "runs" / "ilc-san" / "Hopper" / "seed0"
SAC_RUNS = DOCS / "algorithms-hopper" / "grid" / "algorithms" / "Hopper" / "ilc-san+sac"
CARE_BN_RUN = DOCS / "algorithms-hopper" / "grid" / "algorithms" / "Hopper" / "ilc-san+care-bn" / "seed1"
DAN_RUN = DOCS / "paper-table" / "runs" / "dan" / "Hopper" / "seed0"
SAC_ONLY = ("exploration", "target_actor", "noisy_sigma", "noisy_beta", "noisy_return_reference", "proxy_iterations",
            "proxy_lr")
"""The training settings a SAC run does not use: the choice of a target actor and of an exploration, and the
settings of NoisySAN and Proxy Target."""


def test_no_class_name_is_defined_twice():
    """Each class at the top of a module of ``ilcsan`` has a name no other module's class has (a declaration of
    :mod:`ilcsan.methods` is ``…Declaration``, its training class in :mod:`ilcsan.rl` the bare name). The numpy
    runtime's fallback ``UserError``, defined only when the package is absent, is inside a ``try`` and not counted."""
    defined: dict[str, list[str]] = defaultdict(list)
    for path in sorted(PACKAGE.rglob("*.py")):
        for node in ast.parse(path.read_text(encoding="utf-8")).body:
            if isinstance(node, ast.ClassDef):
                defined[node.name].append(str(path.relative_to(PACKAGE)))
    assert {name: places for name, places in defined.items() if len(places) > 1} == {}


def test_the_default_names_are_the_registered_defaults():
    """:data:`~ilcsan.methods.DEFAULT_ALGORITHM` and :data:`~ilcsan.methods.NO_NORMALIZATION` are the first
    registered of their kinds (:func:`ilcsan.methods.default`) and the defaults of a run and of an actor."""
    assert methods.default("algorithm") == methods.DEFAULT_ALGORITHM == RunConfig().algorithm
    assert methods.default("normalization") == methods.NO_NORMALIZATION == ActorConfig().normalization


# ------------------------------------------------------------------------------------- the old Python names
def _warns_naming(new: str):
    return pytest.warns(DeprecationWarning, match=new)


def test_the_old_python_names_work_and_warn():
    """``TD3Config`` (from :mod:`ilcsan.config` and :mod:`ilcsan`), ``td3_config_class()``, ``RunConfig.td3``,
    ``RunConfig(td3=...)`` and ``methods.TD3_SELECTORS`` give what their new names give, with a DeprecationWarning
    that names the new name."""
    with _warns_naming("TrainingConfig"):
        from ilcsan.config import TD3Config
    assert TD3Config is TrainingConfig is training_config_class()
    with _warns_naming("TrainingConfig"):
        assert ilcsan.TD3Config is TrainingConfig
    with _warns_naming("training_config_class"):
        from ilcsan.config import td3_config_class
        assert td3_config_class() is TrainingConfig
    settings = TrainingConfig(batch_size=32)
    with _warns_naming("RunConfig.training"):
        assert RunConfig(training=settings).td3 is settings
    with _warns_naming(r"RunConfig\(training=...\)"):
        old = RunConfig(task="Pendulum-v1", td3=settings)
    assert old == RunConfig(task="Pendulum-v1", training=settings)
    with pytest.raises(TypeError, match="not both"), warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        RunConfig(training=settings, td3=settings)
    with _warns_naming("KINDS_CHOSEN_BY_TRAINING"):
        assert methods.TD3_SELECTORS == methods.KINDS_CHOSEN_BY_TRAINING
    with warnings.catch_warnings():
        warnings.simplefilter("error", DeprecationWarning)  # the new names do not warn
        assert RunConfig(training=settings).training is settings and ilcsan.TrainingConfig is TrainingConfig


# -------------------------------------------------------------------------------- files that say td3
@pytest.mark.parametrize("folder", [TD3_RUN, DAN_RUN, CARE_BN_RUN, SAC_RUNS / "seed1"],
                         ids=["ilc-san", "dan", "care-bn", "sac"])
def test_a_committed_config_json_that_says_td3_reads(folder):
    """A config.json written before the name ``training`` (committed under docs/) reads with its ``td3`` as the
    training settings, and writes back as ``training``."""
    from ilcsan.runs.directory import RunDirectory

    saved = json.loads((folder / "config.json").read_text())
    assert "td3" in saved and "training" not in saved
    config = RunDirectory(folder).run_config()
    assert config == RunConfig.from_dict(saved)
    assert config.training == TrainingConfig.from_dict(saved["td3"])  # old spellings of a choice in today's
    written = config.for_seed(saved["seed"])
    assert "td3" not in written and RunConfig.from_dict(written).training == config.recorded().training


def test_a_checkpoint_that_says_td3_loads_exports_and_resumes(trained_run, tmp_path):
    """A checkpoint (and config.json) whose run configuration says ``td3``, as written before the name ``training``:
    ``ilcsan.load`` acts with it as with the new one, it exports, and a resume with the run's settings accepts it
    (:func:`~ilcsan.runs.checkpoint.check_resumable`); the run folder's policy.pt, which holds no run configuration,
    loads as before."""
    import numpy as np
    import torch

    from ilcsan.deploy.bundle import export_npz
    from ilcsan.files import safe_torch_load
    from ilcsan.runs.checkpoint import check_resumable
    from ilcsan.runs.directory import RunDirectory

    old = tmp_path / "old"
    shutil.copytree(trained_run / "seed0" if (trained_run / "seed0").is_dir() else trained_run, old)
    state = safe_torch_load(old / "checkpoint.pt", "checkpoint")
    assert "training" in state["config"] and "td3" not in state["config"]
    state["config"] = {("td3" if key == "training" else key): value for key, value in state["config"].items()}
    torch.save(state, old / "checkpoint.pt")
    saved = json.loads((old / "config.json").read_text())
    (old / "config.json").write_text(json.dumps({("td3" if k == "training" else k): v for k, v in saved.items()}))

    config = RunDirectory(old).run_config()
    assert config == RunDirectory(trained_run if (trained_run / "config.json").is_file()
                                  else trained_run / "seed0").run_config()
    check_resumable(RunDirectory(old), safe_torch_load(old / "checkpoint.pt", "checkpoint"), config,
                    state["state_dim"], state["action_dim"])
    observation = np.linspace(-1.0, 1.0, state["state_dim"]).astype(np.float32)
    from_checkpoint = ilcsan.load(old / "checkpoint.pt")
    np.testing.assert_array_equal(from_checkpoint.predict(observation),
                                  ilcsan.load(RunDirectory(old).file("checkpoint.pt")).predict(observation))
    assert export_npz(from_checkpoint, tmp_path / "actor.npz").is_file()
    policy = ilcsan.load(old / "policy.pt")
    assert np.all(np.isfinite(policy.predict(observation)))
    assert export_npz(policy, tmp_path / "policy.npz").is_file()


def test_a_grid_row_that_says_td3_loads(tmp_path):
    """A TOML grid whose rows give their training table as ``td3 = {...}`` loads as one that says ``training``; a row
    with both is refused."""
    from ilcsan.errors import UserError
    from ilcsan.experiments.grid_files import load_grid

    def grid(key: str, extra: str = "") -> Path:
        path = tmp_path / f"{key}.toml"
        path.write_text('name = "mine"\ntasks = ["Hopper"]\n\n[[rows]]\nslug = "proxy"\npreset = "ilc-san"\n'
                        f'{key} = {{ target_actor = "proxy", proxy_iterations = 1 }}\n{extra}')
        return path

    old, new = load_grid(grid("td3")), load_grid(grid("training"))
    assert old == new and old.rows[0].training == {"target_actor": "proxy", "proxy_iterations": 1}
    with pytest.raises(UserError, match="once"):
        load_grid(grid("td3", 'training = { preaction_penalty = 0.1 }\n'))
    committed = DOCS / "intra-idp" / "grid.toml"
    assert len(load_grid(committed).rows) >= 2


# ------------------------------------------------------------------ a run records what its algorithm uses
def test_a_sac_run_records_only_the_settings_it_uses():
    """SAC has no target actor and explores by its own means: its config.json leaves out the settings that choose
    them and theirs, which read back as their defaults; TD3's and DDPG's keep every setting."""
    assert set(methods.unused_settings("sac")) == set(SAC_ONLY)
    assert methods.unused_settings("td3") == methods.unused_settings("ddpg") == methods.unused_settings("ppo") == ()
    sac = RunConfig(algorithm="sac", training=TrainingConfig(noisy_sigma=0.3))  # set, but SAC does not use it
    written = sac.for_seed(0)["training"]
    assert not set(SAC_ONLY) & set(written)
    assert RunConfig.from_dict(sac.for_seed(0)).training == sac.recorded().training == TrainingConfig()
    assert set(SAC_ONLY) <= set(RunConfig().for_seed(0)["training"])


def _folder(source: Path, target: Path, rewrite) -> Path:
    """A copy of the committed run ``source`` without its grid tags (a ``train`` run that reports place by its label
    and settings), its config.json rewritten by ``rewrite``."""
    shutil.copytree(source, target)
    saved = json.loads((target / "config.json").read_text())
    saved.update(table=None, row=None)
    (target / "config.json").write_text(json.dumps(rewrite(saved)))
    return target


@pytest.mark.parametrize("runs", [SAC_RUNS, TD3_RUN.parent], ids=["sac", "td3"])
def test_a_report_puts_old_and_new_runs_of_the_same_settings_in_one_cell(runs, tmp_path):
    """A run written before the name ``training`` (``td3``; a SAC run with every setting) and one written today
    (``training``; a SAC run without the settings SAC does not use) of the same settings have one identity in reports
    (:func:`~ilcsan.analysis.collect.row_identity`, :func:`~ilcsan.analysis.collect.configuration_key`)."""
    from ilcsan.analysis.collect import read_run, row_identity

    seeds = sorted(path for path in runs.iterdir() if (path / "config.json").is_file())[:2]
    old = read_run(_folder(seeds[0], tmp_path / "old", lambda saved: saved))
    new = read_run(_folder(seeds[1], tmp_path / "new",
                           lambda saved: RunConfig.from_dict(saved).for_seed(saved["seed"]) | {"table": None,
                                                                                               "row": None}))
    assert "td3" in json.loads((tmp_path / "old" / "config.json").read_text())
    assert "training" in json.loads((tmp_path / "new" / "config.json").read_text())
    assert old.training and new.training
    assert set(SAC_ONLY).isdisjoint(new.training) == (runs == SAC_RUNS)
    assert row_identity(old) == row_identity(new)
