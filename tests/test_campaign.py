"""Campaigns (bgc experiment): the file is checked like a model, expanded into
runs as written, run on local processes or a Dask cluster with the same rows,
resumed without redoing finished runs; a failing run is recorded and the
campaign goes on; tables and metrics computed as defined."""

import dataclasses
import json
import math
import shutil
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

from bgc.experiment import campaign

from bgc.experiment import campaign_file, one_run, runs_csv
from bgc.errors import BgcError
from bgc.output import tables
from bgc.experiment import metrics

from conftest import ROOT, bgc_cli

CIRCUIT = ROOT / "models" / "circuit.yaml"
TWO_TANK = ROOT / "models" / "two_tank.yaml"

SMALL = f"""\
campaign: small
defaults:
  steps: 80
  filters: [gpf, apf]
  particles: [100]
  seeds: 2
groups:
  - name: grid
    model: {CIRCUIT}
    scenarios: [none, "R2:abrupt:0.6@1.5"]
  - name: draws
    model: {TWO_TANK}
    draws: {{count: 2, change: [0.3, 0.5], onset: [0.3, 0.4], kinds: [abrupt, incipient]}}
    filters: [gpf]
    seeds: 1
tables:
  - title: grid
    groups: [grid]
    metrics: [rt, right, est_error]
    reference:
      source: a reference
      values:
        - {{row: "R2:abrupt:0.6@1.5", filter: gpf, est_error: 5}}
"""


def write(tmp_path: Path, text: str, name: str = "c.yaml") -> Path:
    p = tmp_path / name
    p.write_text(textwrap.dedent(text), encoding="utf-8")
    return p


def without_time(rows):
    return [{k: v for k, v in r.items() if k != "rt"} for r in rows]


# ------------------------------------------------------------------ the file
def test_the_grid_expands_into_every_combination_in_order(tmp_path):
    c = campaign_file.load_campaign(write(tmp_path, SMALL))
    grid = [s for s in c.specs if s.group == "grid"]
    # 2 scenarios x 1 noise x 2 filters x 1 particle count x 2 seeds
    assert len(grid) == 8 and len([s for s in c.specs if s.group == "draws"]) == 2
    assert [s.index for s in c.specs] == list(range(10))
    assert len({s.id for s in c.specs}) == 10
    assert {(s.scenario, s.filter, s.seed) for s in grid} == {
        (sc, f, seed) for sc in ("none", "R2:abrupt:0.6@1.5") for f in ("gpf", "apf") for seed in (0, 1)}
    r2 = next(s for s in grid if s.fault == "R2")
    # R2's nominal value in circuit.yaml is 2.0: 2.0 + 0.6 after the step
    assert (r2.kind, r2.magnitude, r2.onset, r2.parameter_truth) == ("abrupt", 0.6, 1.5, 2.6)


def test_draws_of_sensor_faults_are_in_units_of_the_reading(tmp_path):
    """F12 of the two tanks reads (e2 - e7)/R12 = (20/9 - 4/3)/2 = 4/9 at the
    operating point: a bias of change c is c * 4/9, a drift's slope reaches
    it over the run (300 x 0.5 = 150); the scenario names the sensor."""
    text = f"""\
    campaign: s
    seed: 3
    groups:
      - name: g
        model: {TWO_TANK}
        draws: {{count: 20, change: [0.2, 0.4], onset: [0.3, 0.6], faults: [F12]}}
    """
    c = campaign_file.load_campaign(write(tmp_path, text))
    assert {s.fault for s in c.specs} == {"F12_offset"} and {s.kind for s in c.specs} <= {"bias", "drift"}
    for s in c.specs:
        assert s.scenario.startswith("F12:")
        change = abs(s.magnitude) / (4 / 9) * (150.0 if s.kind == "drift" else 1.0)
        assert 0.2 - 1e-4 <= change <= 0.4 + 1e-4, s.scenario


def test_draws_are_reproducible_and_respect_ranges_and_declared_directions(tmp_path):
    text = f"""\
    campaign: d
    seed: 7
    groups:
      - name: g
        model: {CIRCUIT}
        draws: {{count: 60, change: [0.2, 0.5], onset: [0.3, 0.6], kinds: [abrupt, incipient]}}
    """
    a = campaign_file.load_campaign(write(tmp_path, text))
    b = campaign_file.load_campaign(write(tmp_path, text, "again.yaml"))
    assert [s.scenario for s in a.specs] == [s.scenario for s in b.specs]
    assert len({s.seed for s in a.specs}) == 60  # every draw its own noise
    nominal = {"R1": 1.0, "R2": 2.0, "R3": 1.0, "C1": 0.5, "C2": 1.0, "L": 0.5}  # circuit.yaml
    duration = 300 * 0.05
    for s in a.specs:
        change = abs(s.magnitude) / nominal[s.fault] * (duration if s.kind == "incipient" else 1.0)
        assert 0.2 - 1e-4 <= change <= 0.5 + 1e-4, s.scenario
        assert 0.3 * duration - 0.05 <= s.onset <= 0.6 * duration + 0.05
        if s.fault in ("C1", "C2"):  # declared 'decrease'
            assert s.magnitude < 0
        if s.fault == "R2":  # declared 'increase'
            assert s.magnitude > 0
    assert {s.fault for s in a.specs} >= {"R1", "R2", "C1", "L"}


@pytest.mark.parametrize("body, where, words", [
    ("groups: [{name: g, model: M, scenarios: [none], colour: red}]", ":2:", "unknown key 'colour'"),
    ("groups: [{name: g, model: M}]", ":2:", "either 'scenarios' or 'draws'"),
    ("groups: [{name: g, model: M, scenarios: [none], filters: [ekf]}]", ":2:", "'ekf' is not valid"),
    ("groups: [{name: g, model: M, scenarios: ['R2:abrupt:x@1']}]", ":2:", "not NAME:KIND:MAGNITUDE@TIME"),
    ("groups: [{name: g, model: M, scenarios: ['Rx:abrupt:1@1']}]", ":2:", "'Rx' is no parameter, measurement or input"),
    ("groups: [{name: g, model: M, scenarios: ['R2:abrupt:1@99']}]", ":2:", "outside the run"),
    ("groups: [{name: g, model: nowhere.yaml, scenarios: [none]}]", ":2:", "not found"),
    ("groups: [{name: g, model: M, scenarios: [none, None]}]", ":2:", "list each scenario once"),
    ("groups: [{name: g, model: M, draws: {count: 3, change: [0.5, 0.2], onset: [0.3, 0.5]}}]", ":2:",
     "change range"),
    ("groups: [{name: g, model: M, draws: {count: 3, change: [0.2, 0.5], onset: [0.3, 0.5], faults: [Q]}}]",
     ":2:", "'Q' is not a fault candidate"),
    ("groups: [{name: g, model: M, scenarios: [none], noise: [{name: 'a b', process: 1, measurement: 1}]}]",
     ":2:", "has characters a name may not have"),
    ("groups: [{name: g, model: M, scenarios: [none]}]\ntables: [{title: t, groups: [h], metrics: [rt]}]",
     ":3:", "names no group 'h'"),
    ("groups: [{name: g, model: M, scenarios: [none]}]\n"
     "tables: [{title: t, groups: [g], metrics: [rt], reference: {source: s, values: [{row: x, filter: gpf}]}}]",
     ":3:", "reference row 'x'"),
])
def test_a_bad_campaign_is_one_located_line_without_traceback(tmp_path, body, where, words):
    path = write(tmp_path, "campaign: bad\n" + body.replace("model: M", f"model: {CIRCUIT}") + "\n")
    with pytest.raises(BgcError) as err:
        campaign_file.load_campaign(path)
    assert words in str(err.value) and f"{path}{where}" in str(err.value)
    r = bgc_cli("experiment", path, "-o", tmp_path / "o")
    assert r.returncode == 1 and "Traceback" not in r.stderr and len(r.stderr.strip().splitlines()) == 1
    assert words in r.stderr


def test_the_published_campaign_schema_is_the_packaged_one():
    assert (ROOT / "schemas" / "campaign.schema.json").read_bytes() == \
        (ROOT / "bgc" / "schema" / "campaign.schema.json").read_bytes(), \
        "after editing bgc/schema/campaign.schema.json run: cp bgc/schema/campaign.schema.json schemas/"


@pytest.mark.slow
def test_the_shipped_campaigns_load():
    thesis = campaign_file.load_campaign(ROOT / "experiments" / "thesis_tables.yaml")
    # Tables IV.2 to IV.4: 5 scenarios x 2 filters x 10 seeds, and R_pipe abrupt at the high noise level
    assert len(thesis.specs) == 100 + 20 and len(thesis.tables) == 4
    sweep = campaign_file.load_campaign(ROOT / "experiments" / "sweep.yaml")
    faulty = [s for s in sweep.specs if s.fault]
    for model in ("ro", "circuit", "two_tank"):
        mine = {s.scenario for s in faulty if s.model_name == model}
        free = [s for s in sweep.specs if s.model_name == model and not s.fault]
        assert len(mine) >= 100 and len(free) >= 100
    assert {s.filter for s in sweep.specs} == {"gpf", "apf"} and len({s.noise for s in sweep.specs}) == 2
    # the sweep's draws with the mean test alone and with the whole bank: its mean runs are the sweep's own
    bank = campaign_file.load_campaign(ROOT / "experiments" / "sweep_bank.yaml")
    assert len(bank.specs) == 2 * len(sweep.specs)
    assert {s.id for s in bank.specs if s.detectors == ("mean",)} == {s.id for s in sweep.specs}
    from bgc.diagnosis import detect

    assert {s.detectors for s in bank.specs} == {("mean",), detect.TESTS}
    plants = campaign_file.load_campaign(ROOT / "experiments" / "test_plants.yaml")  # 3 plants x (30 + 20) x 2 x 2
    assert len(plants.specs) == 3 * (30 + 20) * 2 * 2
    assert {s.model_name for s in plants.specs} == {"dc_motor", "orifice_tanks", "mass_spring_damper"}
    sharp = campaign_file.load_campaign(ROOT / "experiments" / "sharp_sensor.yaml")  # 30 draws, 3 filters x 20 fault-free
    assert len(sharp.specs) == 30 + 3 * 20 and {s.model_name for s in sharp.specs} == {"drivetrain"}
    assert {s.filter for s in sharp.specs if s.fault} == {"ckf"}


# ------------------------------------------------------------------ running
def test_a_failing_run_is_recorded_and_does_not_raise(tmp_path):
    c = campaign_file.load_campaign(write(tmp_path, SMALL))
    broken = dataclasses.replace(c.specs[0], model_text="name: [\n")
    row = one_run.run_one(broken)
    assert row["status"] == "failed" and "YAML" in row["failure"] and row["index"] == 0


@pytest.fixture(scope="module")
def local_run(tmp_path_factory):
    """SMALL run on two forked local workers (what a local campaign is): its
    tests are marked slow (ten diagnoses end to end)."""
    folder = tmp_path_factory.mktemp("campaign")
    config = write(folder, SMALL)
    c = campaign_file.load_campaign(config)
    # this process fills its caches first: forked workers must make their own folders
    # (sharing them, two workers once wrote the same model file at once and a run failed)
    assert one_run.run_one(c.specs[1])["status"] == "ok"
    return c, campaign.run_campaign(c, folder / "out", workers=2, progress=False), folder


@pytest.mark.slow
@pytest.mark.long
def test_a_local_campaign_writes_rows_tables_and_plots(local_run):
    c, r, folder = local_run
    out = folder / "out"
    assert r.failed == 0, [row["failure"] for row in r.rows if row["status"] != "ok"]
    assert r.ran == 10 and [row["index"] for row in r.rows] == list(range(10))
    rows = runs_csv.read_rows(out / "runs.csv")
    assert without_time(rows) == without_time(r.rows)
    for row in rows:
        if row["scenario"] == "none":  # fault-free: no alarm expected at the model's noise
            assert row["right"] is None and row["estimate"] is None
        if row["scenario"] == "R2:abrupt:0.6@1.5":
            assert row["detected"] and row["delay"] >= 0 and row["right"]
            assert row["parameter"] == pytest.approx(2.0 + row["estimate"], rel=1e-3)
            assert row["est_error"] == pytest.approx(abs(row["estimate"] - 0.6) / 0.6)
            # a step of R2 by 0.6 (+30 %) is predicted separable from every rival (bgc distinguish)
            assert row["separable"] is True and row["rivals"] is None and row["separation"] >= 0.95
            assert row["detectability"] >= 0.95  # and seen: it was detected
        if row["fault"] is None:
            assert row["separable"] is None and row["separation"] is None and row["detectability"] is None
    text = (out / "tables.md").read_text()
    assert "### grid" in text and "[5]" in text and "## Isolation confusion matrix" in text
    assert (out / "plots" / "distributions.png").read_bytes()[:4] == b"\x89PNG"
    assert (out / "plots" / "confusion_circuit.png").exists()
    page = (out / "report.html").read_text()
    assert page.startswith("<!DOCTYPE html>\n<!-- generated by bgc from ") and "<h2>grid</h2>" in page
    assert page.count('<img src="data:image/png;base64,') == len(list((out / "plots").iterdir()))
    assert "report.html" in json.loads((out / "manifest.json").read_text())["files"]


@pytest.mark.slow
def test_an_interrupted_campaign_resumes_without_redoing_finished_runs(local_run, tmp_path):
    """The fixture's finished campaign folder, copied, its runs.csv cut as a
    killed campaign leaves it, is resumed."""
    c, first, folder = local_run
    out = tmp_path / "resume"
    shutil.copytree(folder / "out", out)
    lines = (out / "runs.csv").read_text().splitlines(keepends=True)
    # keep the header and 8 rows, then a row cut in its last column (the process was killed
    # while writing: 'tr' of 'true' or 'false' read as a value would be wrong); the two runs
    # left (one whose row was cut, one never written) are done again, one per worker
    (out / "runs.csv").write_text("".join(lines[:9]) + lines[9].rstrip("\n")[:-2])
    again = campaign.run_campaign(c, out, workers=2, progress=False)
    assert (again.reused, again.ran) == (8, 2)
    # the cut line is not lost: it is set aside as it was, and its run done again
    assert again.quarantined == 1 and again.quarantine == out / "runs.unread-1.csv"
    assert again.quarantine.read_text() == lines[9].rstrip("\n")[:-2]
    assert without_time(again.rows) == without_time(first.rows)


@pytest.mark.slow
@pytest.mark.process  # a Dask cluster of two worker processes
def test_a_dask_cluster_gives_the_local_rows_row_for_row(local_run):
    distributed = pytest.importorskip("distributed")
    c, local, folder = local_run
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                                  dashboard_address=None) as cluster:
        remote = campaign.run_campaign(c, folder / "dask", scheduler=cluster.scheduler_address, progress=False)
    assert remote.ran == 10 and remote.failed == 0
    assert without_time(remote.rows) == without_time(local.rows)


@pytest.mark.slow
def test_the_campaign_folder_is_bgc_s_own(local_run, tmp_path):
    c, _, folder = local_run
    (tmp_path / "mine.txt").write_text("notes")
    with pytest.raises(BgcError, match="holds no bgc manifest.json"):
        campaign.run_campaign(c, tmp_path, progress=False)
    other = dataclasses.replace(c, name="other")
    with pytest.raises(BgcError, match="holds campaign 'small'"):
        campaign.run_campaign(other, folder / "out", progress=False)
    # a folder bgc compile wrote is bgc's, but not a campaign's: its files must not be replaced
    r = bgc_cli("compile", CIRCUIT, "-o", tmp_path / "gen", "--no-pictures")
    assert r.returncode == 0, r.stderr
    before = sorted(p.name for p in (tmp_path / "gen" / "circuit").rglob("*"))
    with pytest.raises(BgcError, match="another bgc output"):
        campaign.run_campaign(c, tmp_path / "gen" / "circuit", progress=False)
    assert sorted(p.name for p in (tmp_path / "gen" / "circuit").rglob("*")) == before


def test_an_unreachable_scheduler_is_one_line(tmp_path):
    config = write(tmp_path, SMALL)
    started = time.perf_counter()
    r = bgc_cli("experiment", config, "-o", tmp_path / "o", "--scheduler", "tcp://127.0.0.1:9")
    assert r.returncode == 1 and "Traceback" not in r.stderr and "Dask scheduler" in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1
    assert time.perf_counter() - started < 5  # refused: no retries for Dask's 30 s timeout


# ------------------------------------------------------------------ tables and metrics
def test_cells_are_mean_and_sample_sd_and_rates_count_defined_runs():
    rows = [{"status": "ok", "rt": x, "right": r} for x, r in ((1.0, True), (2.0, False), (6.0, None))]
    rows.append({"status": "failed", "rt": 100.0, "right": True})
    assert tables.cell(rows, "rt") == (3.0, math.sqrt(7.0), 3, 0)  # (4 + 1 + 9) / 2 = 7; no NaN
    assert tables.cell(rows, "right") == (0.5, 0.0, 2, 0)
    assert tables.format_cell(tables.cell(rows, "right"), "right") == "1/2"


def test_a_run_whose_metric_is_nan_is_counted_and_said_beside_the_mean():
    """A NaN metric (a filter that diverged) is never dropped from a mean
    without a word: the mean and sd are the other runs', and the cell, the
    summary and summary.json say how many were NaN."""
    def row(mse, rt=1.0, status="ok"):
        return {"status": status, "group": "g", "scenario": "none", "filter": "gpf", "noise": "model",
                "particles": 100, "fault": None, "false_alarm": False, "verdict": "no fault", "rt": rt, "mse": mse}
    rows = [row(0.0004), row(0.0006), row(math.nan), row(math.nan, status="failed")]  # a failed run: not counted
    c = tables.cell(rows, "mse")
    assert (c.mean, c.sd, c.n, c.nan) == (pytest.approx(0.0005), pytest.approx(math.sqrt(2e-8)), 2, 1)
    assert tables.format_cell(c, "mse") == "0.0005 (0.000141; n=2, 1 NaN)"
    assert tables.cell_json(c) == {"mean": c.mean, "sd": c.sd, "n": 2, "nan": 1}
    spec = campaign_file.TableSpec("t", ("g",), "scenario", None, ("mse", "rt"), None)
    assert tables.table_cells(spec, rows)[1] == [["none", "0.0005 (0.000141; n=2, 1 NaN)", "1 (0)"]]
    every = [row(math.nan), row(math.nan)]
    assert tables.format_cell(tables.cell(every, "mse"), "mse") == "NaN (n=0, 2 NaN)"
    assert tables.cell_json(tables.cell(every, "mse")) == {"mean": None, "sd": None, "n": 0, "nan": 2}
    assert "| 1 (0; n=1, 1 NaN) |" in tables.summary_markdown([row(0.1), row(0.1, rt=math.nan)])  # RT s


def test_isolation_is_counted_outside_the_qualitative_and_the_predicted_ambiguity_groups():
    def row(right, ambiguous, separable, delay=2.0):
        return {"status": "ok", "group": "g", "filter": "gpf", "noise": "model", "particles": 100, "fault": "R1",
                "kind": "abrupt", "delay": delay, "right": right, "ambiguous": ambiguous, "separable": separable,
                "verdict": "isolated", "in_candidates": True, "false_alarm": False, "diagnosed": "R1_abrupt"}
    rows = [row(True, False, True), row(False, False, False), row(False, True, True), row(True, False, None),
            row(False, False, True, delay=None)]  # the last was not detected: not counted
    s = tables.summary_rows(rows)[0]
    assert (s["right"], s["detected"]) == (2, 4)
    assert (s["right_outside_ambiguity"], s["outside_ambiguity"]) == (2, 3)
    assert (s["right_separable"], s["separable"]) == (1, 1)
    assert "right where the data separate it (predicted)" in tables.summary_markdown(rows)


def test_detection_is_counted_where_the_data_are_predicted_to_show_the_fault():
    def row(detectability, delay):
        return {"status": "ok", "group": "g", "filter": "gpf", "noise": "model", "particles": 100, "fault": "R1",
                "kind": "abrupt", "delay": delay, "right": delay is not None, "ambiguous": False,
                "separable": True, "verdict": "isolated", "in_candidates": True, "false_alarm": False,
                "diagnosed": "R1_abrupt", "detectability": detectability}
    # shown where the ideal detector at the campaign's 1 % false-alarm rate detects with probability 0.95: a
    # detectability of Phi((1.645 + 2.326) / 2) = 0.9765 or more. Shown: 0.99 (detected), 0.98 (missed); not shown:
    # 0.95 (the ideal detector at 1 % catches it in 83 % of runs only; detected, counted only among all), 0.9,
    # None (no prediction)
    rows = [row(0.99, 3.0), row(0.98, None), row(0.95, 2.0), row(0.9, 1.0), row(None, None)]
    s = tables.summary_rows(rows)[0]
    assert (s["detected"], s["faulty"]) == (3, 5)
    assert (s["detected_shown"], s["shown"]) == (1, 2)
    assert "| 1/2 (50.0 %) |" in tables.summary_markdown(rows)


def test_the_confusion_matrix_counts_truth_against_diagnosis():
    rows = [{"status": "ok", "model": "m", "fault": f, "kind": k, "diagnosed": d}
            for f, k, d in (("R1", "abrupt", "R1_abrupt"), ("R1", "abrupt", "R2_abrupt"), (None, None, "none"))]
    truths, saids, counts = tables.confusion(rows, "m")
    assert truths == ["none", "R1_abrupt"] and counts == {("R1_abrupt", "R1_abrupt"): 1,
                                                          ("R1_abrupt", "R2_abrupt"): 1, ("none", "none"): 1}


def test_convergence_needs_every_later_window_to_pass():
    T = 60
    truth = np.zeros((T, 3))
    std = np.ones((T, 3))
    mean = truth.copy()
    assert metrics.convergence_step(mean, truth, std, 0) == 0
    mean[T - 1] = 10.0  # the last window fails: not converged
    assert metrics.convergence_step(mean, truth, std, 0) is None
    mean[T - 1] = 0.0
    mean[20:25] = 4.0  # NEES 16 on 5 of 10 steps: window average 8 > chi2_0.999(30)/30 = 1.98
    k = metrics.convergence_step(mean, truth, std, 0)
    # a window of 10 steps fails with two of the bad steps (2 x 16 / 10 = 3.2 > 1.99) and passes
    # with one (1.6): the last failing window is [23, 33), holding 23 and 24; from step 33 on,
    # every window that ends there or later holds at most step 24
    assert k == 33


def test_the_chi_square_quantile_matches_tables():
    for q, dof, table in ((0.999, 30, 59.703), (0.99, 50, 76.154), (0.95, 100, 124.342)):
        assert metrics.chi2_quantile(q, dof) == pytest.approx(table, rel=5e-3)


def test_convergence_fails_a_window_with_a_missing_estimate_or_spread():
    T = 60
    truth = np.zeros((T, 2))
    mean = np.full((T, 2), 50.0)  # 50 sd off at every step: never converged
    std = np.ones((T, 2))
    std[10, 0] = 0.0
    assert metrics.convergence_step(mean, truth, std, 0) is None
    mean[:] = 0.0  # right at every step, but no estimate at step 55
    mean[55, 1] = np.nan
    std[10, 0] = 1.0
    # windows of 3 holding step 55 fail: the last is [55, 58); from step 58 on every window passes
    assert metrics.convergence_step(mean, truth, std, 0, window=3) == 58


def test_refine_is_a_setting_and_rows_of_an_older_runs_csv_are_read(tmp_path):
    text = f"""\
    campaign: r
    groups:
      - name: g
        model: {CIRCUIT}
        scenarios: ["R2:abrupt:0.6@5"]
        refine: [false, true]
    """
    c = campaign_file.load_campaign(write(tmp_path, text))
    assert [s.refine for s in c.specs] == [False, True] and c.specs[0].id != c.specs[1].id
    # a runs.csv written before the 'refine' column existed: its rows are read, refine False
    old = runs_csv.COLUMNS[:runs_csv.COLUMNS.index("refine")]
    row = {k: None for k in old} | {"id": "x", "index": 0, "status": "ok", "right": True}
    (tmp_path / "runs.csv").write_text(
        "# generated by bgc\n" + ",".join(old) + "\n" + ",".join(runs_csv.format_value(row[k]) for k in old) + "\n")
    rows = runs_csv.read_rows(tmp_path / "runs.csv")
    assert len(rows) == 1 and rows[0]["refine"] is False and rows[0]["right"] is True


def test_detect_is_a_setting_the_runs_take_and_rows_of_an_older_runs_csv_are_the_mean_test(tmp_path, monkeypatch):
    """``detect: [mean, "variance,drift", all]`` plans each run three times, each with the
    families of tests bgc diagnose --detect would run (the mean test first and
    always); the mean test's runs keep the ids they had before the setting; a
    run's DiagnosisOptions carry them (one_run, the API's diagnose captured);
    two items naming the same tests are refused in a located line; a runs.csv
    written before the column reads as the mean test."""
    text = f"""\
    campaign: d
    groups:
      - name: g
        model: {CIRCUIT}
        scenarios: ["R2:abrupt:0.6@5"]
        detect: [mean, "variance,drift", all]
    """
    c = campaign_file.load_campaign(write(tmp_path, text))
    assert [s.detectors for s in c.specs] == [("mean",), ("mean", "drift", "variance"),
                                              ("mean", "drift", "variance", "frozen", "pooled", "matched")]
    assert len({s.id for s in c.specs}) == 3
    plain = campaign_file.load_campaign(write(tmp_path, text.replace('        detect: [mean, "variance,drift", all]\n', "")))
    assert plain.specs[0].id == c.specs[0].id and plain.specs[0].detectors == ("mean",)
    assert c.specs[2].identity()["detectors"] == "mean,drift,variance,frozen,pooled,matched"
    seen = []

    def diagnose(session, **kw):
        seen.append(kw["options"].detectors)
        raise RuntimeError("stop here")

    from bgc import api
    from bgc.experiment import one_run
    monkeypatch.setattr(api, "diagnose", diagnose)
    row = one_run.run_one(c.specs[1])
    assert seen == [("mean", "drift", "variance")] and row["status"] == "failed" and row["detectors"] == \
        "mean,drift,variance"
    with pytest.raises(BgcError, match=r"c.yaml:6:.*detect: 'all' names the same tests as an item before it"):
        campaign_file.load_campaign(write(tmp_path, text.replace('"variance,drift", all]',
                                                                 '"mean,drift,variance,frozen,pooled,matched", all]')))
    with pytest.raises(BgcError, match=r"detect"):
        campaign_file.load_campaign(write(tmp_path, text.replace('"variance,drift"', '"slope"')))
    old = runs_csv.COLUMNS[:runs_csv.COLUMNS.index("detectors")]
    row = {k: None for k in old} | {"id": "x", "index": 0, "status": "ok", "right": True}
    (tmp_path / "runs.csv").write_text(
        "# generated by bgc\n" + ",".join(old) + "\n" + ",".join(runs_csv.format_value(row[k]) for k in old) + "\n")
    assert runs_csv.read_rows(tmp_path / "runs.csv")[0]["detectors"] == "mean"


def test_numpy_scalars_are_written_as_plain_numbers():
    """A NumPy float's repr is 'np.float64(2.5)': read back, that is no number."""
    assert runs_csv.format_value(np.float64(2.5)) == "2.5" and runs_csv.format_value(2.5) == "2.5"
    assert runs_csv.format_value(np.bool_(True)) == "true" and runs_csv.format_value(np.int64(3)) == "3"
    assert runs_csv.format_value(np.float64("nan")) == "nan" and runs_csv.format_value(None) == ""
