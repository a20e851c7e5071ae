"""Fault injection from the configuration: a commissioning test from the command line, with
the faults injected and detected reported beside the conflict counts."""

from __future__ import annotations

import json

import pytest

from fleet.cli import main
from fleet.config import DEFAULT_CONFIG, parse_config
from plc_runtime.errors import ConfigError

FAULTS = """
[faults]
drop_rate = 0.05
corrupt_rate = 0.05
spoof_rate = 0.02

[[faults.vehicles]]
id = 4
dead_after_s = 30
"""


def test_a_faulty_commissioning_run_reports_injected_and_detected_faults(tmp_path, capsys):
    cfg = tmp_path / "faulty.toml"
    cfg.write_text(DEFAULT_CONFIG.read_text() + FAULTS)
    out = tmp_path / "out"
    assert main(["run", str(cfg), "--duration", "90", "--json", "--out", str(out)]) == 0
    summary = json.loads(capsys.readouterr().out)
    injected, detected = summary["faults"]["injected"], summary["faults"]["detected"]
    assert injected["dropped"] > 0 and injected["corrupted"] > 0 and injected["spoofed"] > 0
    assert detected["crc_errors"] > 0  # every corrupted frame that arrived was caught
    assert summary["head_on_conflicts"] == 0 and summary["node_conflicts"] == 0
    # dead after 30 s: silent, an obstacle where it was last seen (its state may still say
    # suspect, if a forged frame made it so before it died: that wins until it recovers)
    assert summary["tags"]["agv4.stale"] is True
    assert summary["vehicles"]["4"]["state"] in ("stale", "suspect")
    assert summary["recipes_completed"] >= 1


def test_fault_rates_apply_to_every_vehicle_and_can_be_overridden():
    cfg = parse_config(DEFAULT_CONFIG.read_text() + FAULTS, "f.toml")
    assert set(cfg.faults) == {1, 2, 3, 4}
    assert cfg.faults[1].corrupt_rate == 0.05 and cfg.faults[1].dead_after is None
    assert cfg.faults[4].dead_after == 30.0 and cfg.faults[4].spoof_rate == 0.02
    assert parse_config(DEFAULT_CONFIG.read_text(), "d.toml").faults == {}


@pytest.mark.parametrize(
    "extra, says",
    [
        ("[faults]\ndrop_rate = 1.5\n", "faults.drop_rate: must be in 0.0..1.0, got 1.5"),
        ("[faults]\nloss = 0.1\n", "faults.loss: unknown key"),
        ("[[faults.vehicles]]\nid = 9\n", "faults.vehicles[0].id: no vehicle 9 in [[vehicles]]"),
        (
            "[[faults.vehicles]]\nid = 1\nstall_after_s = -1\n",
            "faults.vehicles[0].stall_after_s: must be >= 0, got -1.0",
        ),
    ],
)
def test_bad_fault_settings_name_the_key(extra, says):
    with pytest.raises(ConfigError) as err:
        parse_config(DEFAULT_CONFIG.read_text() + "\n" + extra, "f.toml")
    assert str(err.value) == f"f.toml: {says}"


def test_the_vehicles_process_reports_every_injected_fault_kind(tmp_path):
    """The monitor report of vehicles in their own process, which a run's summary shows as
    faults.injected, counts the same kinds as a run with the vehicles in-process."""
    from ports import free_base_port

    from fleet.report import INJECTED

    cfg = tmp_path / "ft.toml"
    cfg.write_text(DEFAULT_CONFIG.read_text() + "\n[faults]\ndrop_rate = 0.1\ndelay_rate = 0.5\n")
    report = tmp_path / "m.json"
    args = ["vehicles", "--config", str(cfg), "--modbus-base-port", str(free_base_port(4))]
    assert main([*args, "--duration", "0.5", "--monitor-out", str(report)]) == 0
    injected = json.loads(report.read_text())["faults_injected"]
    assert tuple(injected) == INJECTED and "delays" in injected
