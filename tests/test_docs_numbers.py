"""The figures the docs quote are the code's (issue 45): the step's onset
window, the detector's windows and false-alarm probability, the default
filter, particles and identification, the symbols' samples, a drift's onset
grid, the hypotheses' tests, the refining and ranking grids, the detector's
runs of ``bgc distinguish``.

Each figure has a pattern per way the docs (README.md and docs/*.md but the
dated notebook docs/results.md) state it; every place a pattern finds must
say the code's value, read from its constants (or, where the code has a
number inline, from what it does), and each pattern must find its places: a
doc reworded past its pattern fails here instead of passing unchecked. The
text is read with its whitespace collapsed, so a sentence may wrap lines.
"""

from __future__ import annotations

import bisect
import re
from pathlib import Path

import pytest

from bgc.api.detection import RUNS
from bgc.cli.main import build_parser
from bgc.diagnosis.detect import DetectorOptions, union_threshold
from bgc.diagnosis.loop import onsets_tried
from bgc.diagnosis.onsets import ONSET_GROWTH
from bgc.diagnosis.options import DiagnosisOptions, KalmanOptions
from bgc.diagnosis.values import Detection

from conftest import ROOT

DEFAULT = DiagnosisOptions()

#: The docs that state the code's figures (docs/results.md is a dated notebook of measurements).
DOCS = [ROOT / "README.md", *sorted(p for p in (ROOT / "docs").glob("*.md") if p.name != "results.md")]

NUMBER = r"(\d+(?:\.\d+)?)"


def _read(path: Path) -> tuple[str, list[int], list[int]]:
    """The doc's text with every run of whitespace one space, and per word its
    offset there and its line in the file (for the messages)."""
    raw = path.read_text(encoding="utf-8")
    words = list(re.finditer(r"\S+", raw))
    offsets, lines, offset, line, pos = [], [], 0, 1, 0
    for w in words:
        line += raw.count("\n", pos, w.start())
        pos = w.start()
        offsets.append(offset)
        lines.append(line)
        offset += len(w.group()) + 1
    return " ".join(w.group() for w in words), offsets, lines


TEXTS = {p.relative_to(ROOT).as_posix(): _read(p) for p in DOCS}


def _says(got: str, expected, scale: float) -> bool:
    """Whether a doc's figure ``got`` is ``expected`` (a number: times ``scale``)."""
    return got == expected if isinstance(expected, str) else float(got) * scale == pytest.approx(expected)


def check(pattern: str, expected: tuple, places: int = 1, scale: float = 1.0) -> None:
    """Every place the docs match ``pattern`` says ``expected`` in its groups
    (a number times ``scale``: 0.01 for a percentage), and there are at least
    ``places`` of them."""
    found = []
    for doc, (text, offsets, lines) in TEXTS.items():
        for m in re.finditer(pattern, text):
            found.append((f"{doc}:{lines[bisect.bisect_right(offsets, m.start()) - 1]}", m))
    assert len(found) >= places, (f"{pattern!r} finds {len(found)} place(s) in the docs, not {places}: "
                                  f"reworded? update the pattern")
    wrong = [f"{where}: {m.group()!r}" for where, m in found
             if not all(_says(g, e, scale) for g, e in zip(m.groups(), expected, strict=True))]
    assert not wrong, f"the docs say other than the code's {expected}:\n" + "\n".join(wrong)


#: An alarm at step 200 of a 400-step record, its change point at step 150: the onsets the loop tries around it.
ALARM, STEPS = Detection(200, "y", 1, 9.0, 4.0, 150), 400


def test_a_steps_onset_window():
    """The loop's own window (its +2 is inline in _onsets): the README once
    said -5, docs/commands.md kept it. The Kalman filters' reach the alarm."""
    near = onsets_tried(DEFAULT, ALARM, STEPS)[1]
    before, after = ALARM.onset_step - min(near), max(near) - ALARM.onset_step
    assert before == DEFAULT.near
    check(r"(\d+) before (?:it )?to (\d+) after", (before, after), places=2)
    kalman = onsets_tried(DEFAULT, ALARM, STEPS)[4][False]
    assert (kalman[0], kalman[-1]) == (ALARM.onset_step - before, ALARM.step)
    check(r"every sample from (\d+) before the\s+detector's change point up to the alarm's", (before,))


def test_the_detectors_windows():
    """The Z-tests' windows (the symbols' too: the loop reads them with the same)."""
    assert DEFAULT.windows == DetectorOptions().windows
    windows = r"windows of (\d+(?:, \d+)* and \d+) samples"
    check(windows, (", ".join(map(str, DEFAULT.windows[:-1])) + f" and {DEFAULT.windows[-1]}",), places=3)


def test_the_false_alarm_probability_and_the_threshold_it_gives():
    """Per horizon, as a percentage, as alpha and in bgc distinguish's line;
    section 2's threshold of the RO plant is the union bound's at it."""
    alpha = DEFAULT.false_alarm
    assert alpha == DetectorOptions().false_alarm
    check(r"false-alarm (?:probability|rate)[^()]{0,40}\(" + NUMBER + " %", (alpha,), places=3, scale=0.01)
    check(r"default alpha is " + NUMBER, (alpha,))
    check(r"false-alarm probability " + NUMBER + " per", (alpha,), places=3)  # bgc distinguish's transcripts
    # section 2's example: the RO plant's threshold at the default alpha and windows
    text = TEXTS["docs/diagnosis.md"][0]
    m = re.search(r"\(T = (\d+), (\d+) sensors, (\d+) windows\) c = (\d+\.\d+)", text)
    assert m, "docs/diagnosis.md: the RO plant's threshold example is gone: update the pattern"
    steps, sensors, windows = map(int, m.groups()[:3])
    assert windows == len(DEFAULT.windows)
    assert m.group(4) == f"{union_threshold(alpha, steps * sensors * windows):.2f}", m.group()


def test_the_default_filter_and_particles(tmp_path):
    """The options', the command line's and a campaign's defaults agree, and the docs say them."""
    from bgc.experiment.campaign_file import load_campaign

    method, particles = DEFAULT.filter, DEFAULT.particles
    parser = build_parser()
    for args in (["diagnose", "m"], ["monitor", "m", "--data", "-"]):
        parsed = parser.parse_args(args)
        assert (parsed.filter, parsed.particles) == (method, particles), args
    campaign = tmp_path / "c.yaml"
    campaign.write_text(f"campaign: c\ngroups:\n  - name: g\n    model: {ROOT / 'models' / 'circuit.yaml'}\n"
                        "    scenarios: [none]\n", encoding="utf-8")
    spec = load_campaign(campaign).specs[0]
    assert (spec.filter, spec.particles) == (method, particles)
    check(r"`--filter [a-z|]+` \(default `(\w+)`", (method,))
    check(r"filters: \[[^\]]*\] +# default \[(\w+)\]", (method,))
    check(r"`--particles N` \(default (\d+)\)", (particles,))
    check(r"with (\d+) \(the default\)", (particles,))
    check(r"default of (\d+) particles", (particles,))
    check(r"particles: \[[^\]]*\] +# default \[(\d+)\]", (particles,))
    check(r"bgc's detector \((\w+), (\d+) particles", (method, particles), places=3)  # bgc distinguish's transcripts


def test_the_default_identification():
    """The options' and the command line's."""
    assert build_parser().parse_args(["diagnose", "m"]).identify == DEFAULT.identify
    check(r"`--identify [a-z|]+` \(default `(\w+)`", (DEFAULT.identify,))
    check(r'by default \(`identify = "(\w+)"`', (DEFAULT.identify,))


def test_the_symbols_samples_after_the_alarm():
    check(r"`symbol_steps` \((\d+)\)", (DEFAULT.symbol_steps,))


def _spacing(options: DiagnosisOptions) -> int:
    """The particle filters' spacing of a drift's onsets near the alarm, as
    the loop lays them (inline in _onsets: 8 with the Kalman filters, else 4)."""
    reach = onsets_tried(options, ALARM, STEPS)[0]  # also the change point and the sample before it
    return min(ALARM.step - k for k in reach if k < ALARM.step and k not in (ALARM.onset_step - 1, ALARM.onset_step))


def test_a_drifts_onset_grid():
    """How far back a drift's onsets reach, and how far apart they lie: the
    particle filters' by default and with ``identify="filter"``, the Kalman
    filters'."""
    search, history, growth = DEFAULT.search, DEFAULT.history, round(1 / ONSET_GROWTH)
    by_default, with_filter = _spacing(DEFAULT), _spacing(DiagnosisOptions(identify="filter"))
    # section 4: the particle filters' grid, extended back (--identify filter)
    check(r"every (\d+) samples back to (\d+) samples before the alarm \(`DiagnosisOptions\.spacing`",
          (with_filter, search))
    check(r"lies more than (\d+) samples before the alarm, then back by another (\d+) samples at a time, up to "
          r"(\d+) before the alarm \(`history`\); further back than (\d+) samples the onsets are 1/(\d+) of",
          (search, search, history, search, growth))
    check(r"the particle filters' is every (\d+) samples, not extended", (by_default,))
    check(r"so with `--identify filter` it stays at (\d+)", (with_filter,))
    # section 6: the Kalman filters' grid, and the particle filters' beside it
    check(r"a drift's are every (\d+) samples \(`KalmanOptions\.spacing`\) back to (\d+) before the alarm",
          (KalmanOptions().spacing, search))
    check(r"then batches of (\d+) samples further back \(1/(\d+) of the distance to the alarm apart\), up to (\d+)",
          (search, growth, history))
    check(r"started every (\d+) samples \(`DiagnosisOptions\.spacing`\) instead of every (\d+)",
          (by_default, with_filter))
    check(r"they keep the (\d+) samples", (with_filter,))


def test_the_hypotheses_tests():
    """The consistency test's probability, the Bayes factor that drops a
    survivor, the posterior a verdict's candidates hold."""
    check(r"probability of " + NUMBER + " of (?:rejecting a filter|an alarm on the true model)",
          (DEFAULT.rejection,), places=2)
    check(r"Bayes factor above (\d+)", (DEFAULT.bayes_factor,), places=2)
    check(r"the Bayes factor of (\d+) drops", (DEFAULT.bayes_factor,))
    check(r"at least (\d+) times less probable \(the Bayes factor", (DEFAULT.bayes_factor,))
    check(r"`isolation_level`,? \(?" + NUMBER, (DEFAULT.isolation_level,), places=2)


def test_the_refining_and_ranking_grids():
    """``--refine``'s grid and ``--rank``'s: onsets, magnitudes, particles."""
    grid, rank = DEFAULT.grid, DEFAULT.rank_grid
    assert grid.particles == rank.particles
    check(r"It takes the (\d+) most probable onsets and (\d+) magnitudes", (grid.onsets, grid.points))
    check(r"for its (\d+) most probable onsets and (\d+) magnitudes", (rank.onsets, rank.points))
    check(r"bootstrap (?:particle )?filter of (\d+) particles with the magnitude held fixed", (grid.particles,),
          places=2)


def test_bgc_distinguishs_detector_runs():
    """The simulated runs bgc distinguish measures the detector on."""
    check(r"simulated runs \((\d+) by default\)", (RUNS,))
    check(r"`--detector-runs N` runs \(default (\d+)", (RUNS,))


def test_the_drift_tests_thresholds_on_a_kalman_observers_residuals():
    """docs/diagnosis.md section 2.1's thresholds of the drift test (three
    sensors over 300 steps, all six tests at the default alpha): the chain
    bound's for a window read whole, the gapped windows', the union bound's."""
    from bgc.diagnosis.detect import TESTS

    o = DetectorOptions(DEFAULT.false_alarm, DEFAULT.windows, 300, TESTS)
    figures = (o.drift_threshold(3, exact=True), o.drift_gapped_threshold(3), o.drift_threshold(3))
    check(r"With all six tests at 1 %, three sensors over 300 steps: " + NUMBER + r" for a window read whole and "
          + NUMBER + r" for one with a gap, instead of " + NUMBER, tuple(round(v, 2) for v in figures))
