"""Energy model (Section V-F): the paper's firing rates give its operation counts and energies, and the
firing rates measured on a hand-made actor equal the hand-computed ones."""

from __future__ import annotations

import json

import numpy as np
import pytest
from spiking_policies import HAND_RATES, HAND_SOP, hand_made_policy, observations, random_policy

from ilcsan.analysis.energy import (
    CMOS_45NM,
    GROUP_FC,
    INTRA_FC,
    PAPER_COSTS,
    count_operations,
    energy_report,
    firing_rates,
    intra_synapses,
    measure_firing_rates,
    paper_report,
    synaptic_layers,
)
from ilcsan.analysis.energy_tables import TASK_ORDER, energy_table
from ilcsan.cli import build_parser
from ilcsan.cli.grid_commands import cmd_energy
from ilcsan.errors import UserError
from ilcsan.paper.published import ENERGY_NJ, FIRING_RATES, OP_COUNTS

T = 5
PAPER_LAYERS = ("fc1", "fc2", "fc3", "group_fc", "intra_fc")
OUR_NAMES = ("FC1", "FC2", "FC3", GROUP_FC, INTRA_FC)


def ops(report) -> dict[str, float]:
    return {layer.name: layer.sop or layer.flop for layer in report.layers}


def published_ops(actor: str, task: str) -> dict[str, int]:
    row = OP_COUNTS[actor][task]
    return {ours: getattr(row, paper) for ours, paper in zip(OUR_NAMES, PAPER_LAYERS, strict=True)
            if getattr(row, paper) is not None}


# ------------------------------------------------------------------------------------------- DAN
def test_dan_ant_is_96000_flop_and_1200_nj():
    report = paper_report("dan", "Ant")
    assert report.total_flop == 256 * (256 + 111 + 8) == 96_000
    assert report.total_sop == 0
    assert report.energy_nj() == pytest.approx(1200.0)


@pytest.mark.parametrize("task", TASK_ORDER)
def test_dan_energy_matches_table_power(task):
    assert round(paper_report("dan", task).energy_nj(), 1) == ENERGY_NJ["dan"][task]


# --------------------------------------------------------------------------------------- ILC-SAN
def test_ilcsan_ant_208278_sop_is_16_nj():
    assert round(OP_COUNTS["ilc-san"]["Ant"].total_sop * PAPER_COSTS.sop_pj / 1000, 1) == 16.0
    report = paper_report("ilc-san", "Ant")
    assert report.total_flop == 0
    assert report.total_sop == pytest.approx(208_278, rel=0.003)
    assert round(report.energy_nj(), 1) == 16.0


@pytest.mark.parametrize("task", TASK_ORDER)
def test_ilcsan_energy_matches_table_power(task):
    assert round(paper_report("ilc-san", task).energy_nj(), 1) == ENERGY_NJ["ilc-san"][task]
    assert round(OP_COUNTS["ilc-san"][task].total_sop * PAPER_COSTS.sop_pj / 1000, 1) == ENERGY_NJ["ilc-san"][task]


@pytest.mark.parametrize("task", ["HalfCheetah", "Hopper", "Walker2d"])
def test_ilcsan_op_counts_exact_per_layer(task):
    ours = ops(paper_report("ilc-san", task))
    for name, printed in published_ops("ilc-san", task).items():
        assert round(ours[name]) == printed, name
    assert round(sum(ours.values())) == OP_COUNTS["ilc-san"][task].total_sop


@pytest.mark.parametrize("actor", ["popsan", "ilc-san"])
@pytest.mark.parametrize("task", TASK_ORDER)
def test_snn_op_counts_within_rounding_of_the_rates(actor, task):
    """Within 0.3 % of Table op — except ILC-SAN Ant FC1 (−1.4 %) — and always inside the interval the
    printed rate and the printed integer allow (2.8 % means 2.75-2.85 %)."""
    ours = ops(paper_report(actor, task))
    layers = {layer.name: layer for layer in paper_report(actor, task).layers}
    for name, printed in published_ops(actor, task).items():
        if actor == "popsan" and name == GROUP_FC:
            continue  # printed as T·fr·Din·Dout "FLOP": test_popsan_group_fc_discrepancy
        per_rate = layers[name].sop / layers[name].rate  # T·Din·Dout
        low, high = (layers[name].rate - 0.0005) * per_rate - 0.5, (layers[name].rate + 0.0005) * per_rate + 0.5
        assert low <= printed <= high, name
        if (actor, task, name) == ("ilc-san", "Ant", "FC1"):
            assert ours[name] == pytest.approx(39_782.4) and printed == 40_351
        else:
            assert ours[name] == pytest.approx(printed, rel=0.003), name


@pytest.mark.parametrize("task", TASK_ORDER)
def test_intra_fc_rate_is_spikes_of_steps_1_to_T_minus_1_over_T(task):
    """Table op's Intra FC = T·fr·M·P² with the authors' rate convention (÷ T, not ÷ (T−1))."""
    rate = FIRING_RATES["ilc-san"][task].intra_fc
    action_dim = {"Ant": 8, "HalfCheetah": 6, "Hopper": 3, "Walker2d": 6}[task]
    printed = OP_COUNTS["ilc-san"][task].intra_fc
    assert round(T * rate * action_dim * 10 * 10) == printed
    assert round((T - 1) * rate * action_dim * 10 * 10) != printed
    assert ops(paper_report("ilc-san", task))[INTRA_FC] == pytest.approx(printed, abs=0.5)


# ---------------------------------------------------------------------------------------- PopSAN
POPSAN_DISCREPANCY = {  # task: (Table op's Group FC "FLOP", M·P_out, nJ from Table op, nJ printed)
    "Ant": (336, 80, 21.9, 18.7), "HalfCheetah": (208, 60, 17.4, 15.5),
    "Hopper": (69, 30, 23.1, 22.6), "Walker2d": (158, 60, 22.0, 20.8),
}


@pytest.mark.parametrize("task", TASK_ORDER)
def test_popsan_group_fc_discrepancy(task):
    """Table op prints PopSAN's Group FC as T·fr·Din·Dout FLOP; Table power charges Din·Dout FLOP."""
    table_op_flop, din_dout, table_op_nj, printed_nj = POPSAN_DISCREPANCY[task]
    row = OP_COUNTS["popsan"][task]
    rate = FIRING_RATES["popsan"][task].group_fc
    assert row.group_fc == table_op_flop == round(T * rate * din_dout)
    report = paper_report("popsan", task)
    assert report.total_flop == din_dout  # our count: the stated formula
    assert round(report.energy_nj(), 1) == printed_nj == ENERGY_NJ["popsan"][task]
    sop_nj = row.total_sop * PAPER_COSTS.sop_pj / 1000
    assert round(sop_nj + din_dout * PAPER_COSTS.flop_pj / 1000, 1) == printed_nj
    assert round(sop_nj + table_op_flop * PAPER_COSTS.flop_pj / 1000, 1) == table_op_nj != printed_nj


# ------------------------------------------------------------------------------------ structure
def test_layer_kinds_follow_the_inputs():
    from ilcsan.config import actor_config

    mdc = {layer.name: layer for layer in synaptic_layers(actor_config("mdc-san"), 11, 3)}
    assert mdc["FC1"].input_kind == "analog" and mdc["FC2"].input_kind == "spikes"
    assert mdc[GROUP_FC].input_kind == "rates" and INTRA_FC not in mdc
    counts = {c.name: c for c in count_operations(list(mdc.values()), {"FC2": 0.5, "FC3": 0.5, GROUP_FC: 0.4}, T)}
    assert counts["FC1"].flop == T * 110 * 256  # analog input: Din·Dout FLOP at each of the T steps
    assert counts[GROUP_FC].flop == 30 and counts[GROUP_FC].sop == 0
    assert [layer.name for layer in synaptic_layers(actor_config("ilc-san", hidden=(64,) * 4), 11, 3)] == [
        "FC1", "FC2", "FC3", "FC4", "FC5", GROUP_FC, INTRA_FC]
    assert intra_synapses("intra", 3, 10) == 300 and intra_synapses("self", 3, 10) == 30
    assert intra_synapses("lateral+bias", 3, 10) == 270 and intra_synapses("bias", 3, 10) == 0
    with pytest.raises(UserError, match="firing rate"):
        count_operations(synaptic_layers(actor_config("ilc-san"), 11, 3), {}, T)


def test_45nm_costs():
    report = paper_report("ilc-san", "Hopper")
    assert report.energy_nj(CMOS_45NM) == pytest.approx(report.total_sop * 0.9 / 1000)
    assert paper_report("dan", "Ant").energy_nj(CMOS_45NM) == pytest.approx(96_000 * 4.6 / 1000)


# ------------------------------------------------------------------------------- measured rates
def test_measured_rates_of_a_hand_made_actor_equal_hand_computed():
    policy = hand_made_policy()
    rates = measure_firing_rates(policy, observations(policy, 7))
    assert rates.inferences == 7
    assert rates.rates == pytest.approx(HAND_RATES, abs=1e-12)
    report = energy_report(policy, rates)
    assert ops(report) == pytest.approx(HAND_SOP, abs=1e-9)
    assert report.total_sop == pytest.approx(71) and report.total_flop == 0


def test_firing_rates_over_an_episode_at_batch_1():
    policy = hand_made_policy()
    rates = firing_rates(policy, "Pendulum-v1", episodes=1, seed=0)
    assert rates.inferences == 200  # Pendulum's time limit
    assert rates.rates == pytest.approx(HAND_RATES, abs=1e-12)


def test_measured_rates_of_a_random_actor_match_its_spikes():
    policy = random_policy(hidden=(32, 32))
    batch = observations(policy, 12)
    output = policy.run(batch)
    rates = measure_firing_rates(policy, batch).rates
    spikes = output.output_spikes[0].double()
    assert rates["FC1"] == pytest.approx(float(output.layer_inputs[0].double().mean()))
    assert rates["FC3"] == pytest.approx(float(output.layer_inputs[2].double().mean()))
    assert rates[GROUP_FC] == pytest.approx(float(spikes.mean()))
    assert rates[INTRA_FC] == pytest.approx(float(spikes[:-1].sum() / spikes.numel()))
    assert min(rates.values()) > 0.02 and max(rates.values()) < 0.98


def test_dan_has_no_rates_to_measure():
    policy = random_policy("dan")
    with pytest.raises(UserError, match="no spikes"):
        measure_firing_rates(policy, observations(policy))
    assert energy_report(policy).total_flop == 11 * 256 + 256 * 256 + 256 * 3


# ----------------------------------------------------------------------------------- tables, CLI
def test_energy_table_reproduces_the_paper_layout():
    text = energy_table([paper_report(actor, task) for actor in ("popsan", "ilc-san") for task in TASK_ORDER])
    assert "| Ant | ILC-SAN | 2.8% | 35.5% | 49.0% | 41.3% | 31.5% |" in text
    assert "| Ant | PopSAN | 42624 SOP | 127140 SOP | 59699 SOP | 80 FLOP | − | 229463 SOP + 80 FLOP |" in text
    assert "| Ant | 1200.0* | 18.7 | 16.0 |" in text
    assert "| Hopper | 864.0* | 22.6 | 8.2 |" in text


def test_energy_table_averages_runs_of_one_actor():
    first, second = paper_report("ilc-san", "Hopper"), paper_report("ilc-san", "Walker2d")
    second = type(second)(first.label, first.task, first.state_dim, first.action_dim, first.timesteps,
                          second.layers, 0, "other")
    text = energy_table([first, second])
    mean_fc1 = (0.165 + 0.159) / 2
    assert f"| Hopper | ILC-SAN | {100 * mean_fc1:.1f}% |" in text


def test_cmd_energy_on_a_trained_run(trained_run, capsys):
    args = build_parser().parse_args(["energy", str(trained_run), "--json"])
    assert cmd_energy(args) == 0
    data = json.loads(capsys.readouterr().out)
    (run,) = data["runs"]
    assert run["label"] == "ilc-san" and run["inferences"] == 200
    assert [layer["name"] for layer in run["layers"]] == ["FC1", "FC2", "FC3", GROUP_FC, INTRA_FC]
    assert run["total_sop"] > 0 and run["total_flop"] == 0
    args = build_parser().parse_args(["energy", str(trained_run), str(trained_run)])
    assert cmd_energy(args) == 0
    text = capsys.readouterr().out
    assert "Energy per inference" in text and "Table op" in text and "Table power" in text


def test_cmd_energy_user_errors(tmp_path):
    with pytest.raises(UserError):
        cmd_energy(build_parser().parse_args(["energy", str(tmp_path / "missing")]))
    with pytest.raises(UserError, match="the following arguments are required: runs"):
        build_parser().parse_args(["energy"])
    with pytest.raises(UserError, match="episodes"):
        firing_rates(hand_made_policy(), "Pendulum-v1", episodes=0)


def test_report_to_dict_is_json():
    report = energy_report(hand_made_policy(), measure_firing_rates(hand_made_policy(), np.zeros((2, 3))))
    data = json.loads(json.dumps(report.to_dict()))
    assert data["total_sop"] == pytest.approx(71)
    assert set(data["energy_nj"]) == {PAPER_COSTS.name, CMOS_45NM.name}
