"""The report concludes: one sentence per store with the stored ratio and its interval, the
ratio plot and the distribution of times, and renders of the first feasible plan BOX finds.
Run on the small planar store that stage=all makes (the ``made`` fixture)."""

from __future__ import annotations

import dataclasses
import json
import math
import re

import numpy as np
import pytest

from box_core.stats import RATIO_INTERVAL_METHOD
from pipeline.report.conclusions import conclude, sentence
from pipeline.report.data import load
from pipeline.report.figures import ORACLES, label
from pipeline.report.renders import first_feasible

FACTOR = re.compile(r"BOX finds a first feasible plan ([\d.]+)× \[([\d.]+), ([\d.]+)\] "
                    r"(faster|slower) than ([A-Z-]+)")


def stored_competitor(res) -> dict:
    """The non-oracle line with the lowest stored ratio to BOX, found here independently."""
    lines = [line for line in res.summary["selectors"]
             if line["name"] not in ("box", "oracle", "fastest")]
    return min(lines, key=lambda line: line["speedup"])


def test_the_sentence_states_the_stored_ratio_and_interval_on_the_first_screen(made):
    store, report = made
    res = load(store)
    line = stored_competitor(res)
    md = (report / "report.md").read_text()
    found = FACTOR.search(md)
    assert found, md[:2000]
    factor, low, high, word, name = found.groups()
    assert name == label(line["name"])
    expected = (line["speedup"], line["speedup_low"], line["speedup_high"])
    if word == "slower":  # BOX's mean time is the longer: the factor and the ends invert
        expected = (1 / expected[0], 1 / expected[2], 1 / expected[1])
    assert [factor, low, high] == [f"{v:.3g}" for v in expected]
    assert (word == "faster") == (line["speedup"] >= 1)
    assert f"95 % {RATIO_INTERVAL_METHOD} interval" in md
    includes_one = line["speedup_low"] <= 1 <= line["speedup_high"]
    assert ("the difference is not resolved" in md) == includes_one
    # first screen: the sentence comes before any table and before every figure but the
    # ratio plot that shows it
    at = found.start()
    assert at < md.index("|") and at < md.index("![") < md.index("fig_ratio_to_box.png")
    first_table = md.index("|")
    assert md.index("fig_ratio_to_box.png") < first_table < md.index("fig3_first_feasible.png")
    page = (report / "report.html").read_text()
    assert page.index('<p class="lead">') < page.index("<table>")
    assert found.group(0) in page


def test_report_json_keeps_the_conclusion(made):
    store, report = made
    numbers = json.loads((report / "report.json").read_text())[str(load(store).path)]
    conclusion = conclude(load(store))
    assert numbers["conclusion"]["sentence"] == conclusion.sentence
    assert numbers["conclusion"]["competitor"] == stored_competitor(load(store))["name"]
    assert numbers["conclusion"]["ratio"] == conclusion.ratio


def test_the_best_competitor_is_chosen_and_oracles_never(made):
    res = load(made[0])
    summary = json.loads(json.dumps(res.summary))
    for line in summary["selectors"]:
        line["speedup"], line["speedup_low"], line["speedup_high"] = 2.0, 1.5, 2.5
        if line["name"] in ORACLES:
            line["speedup"], line["speedup_low"], line["speedup_high"] = 0.1, 0.05, 0.2
    static = next(line for line in summary["selectors"] if line["name"] == "static")
    static.update(speedup=1.25, speedup_low=0.9, speedup_high=1.6)
    c = conclude(dataclasses.replace(res, summary=summary))
    assert c.competitor == "static" and c.ratio == 1.25 and not c.resolved
    assert "1.25× [0.9, 1.6] faster than STATIC" in c.sentence
    assert "the interval includes 1: the difference is not resolved" in c.sentence
    static.update(speedup=1.1, speedup_low=1.05, speedup_high=1.2)
    c = conclude(dataclasses.replace(res, summary=summary))
    assert c.resolved and "1.1× [1.05, 1.2] faster than STATIC" in c.sentence
    assert "not resolved" not in c.sentence


@pytest.mark.parametrize("ratio, low, high, text", [
    (1.36, 1.23, 1.51, "BOX finds a first feasible plan 1.36× [1.23, 1.51] faster than STATIC"),
    (0.5, 0.4, 0.8, "BOX finds a first feasible plan 2× [1.25, 2.5] slower than STATIC"),
    (0.5, 0.4, 1.25, "2× [0.8, 2.5] slower than STATIC (mean time to a first feasible plan "
                     "over the 30 instances both solved; 95 % paired BCa bootstrap interval), "
                     "but the interval includes 1: the difference is not resolved on 30"),
    (2.0, math.nan, math.nan, "2× faster than STATIC"),
])
def test_the_sentence_reads_right_either_way(ratio, low, high, text):
    said = sentence("planar / rrt_connect", "STATIC", ratio, low, high, 0.95, 30)
    assert said.startswith("On planar / rrt_connect, ") and said.endswith(".")
    assert text in said
    if math.isnan(low):
        assert "with no interval from 30 instances" in said


def test_the_new_figures_are_written_and_embedded(made):
    _, report = made
    for stem in ("fig_time_distribution", "fig_ratio_to_box"):
        for fmt in ("png", "svg"):
            assert (report / f"{stem}.{fmt}").stat().st_size > 5000
    svg = (report / "fig_time_distribution.svg").read_text()
    assert "time to first feasible plan (s, log scale)" in svg
    md = (report / "report.md").read_text()
    assert "Distribution of the time to first feasible plan" in md
    assert "fig_time_distribution.png" in md
    assert md.count("paired BCa bootstrap") >= 3  # sentence, plot caption, note


def test_renders_show_the_first_feasible_plan_box_finds(made):
    store, report = made
    res = load(store)
    md = (report / "report.md").read_text()
    shown = re.findall(r"renders/store0-instance(\d+)-constraint(\d+)\.png", md)
    shown = list(dict.fromkeys(shown))
    assert len(shown) == 3
    rows = []
    for i, j in ((int(a), int(b)) for a, b in shown):
        assert res.feasible[i, j]  # the plan drawn is feasible in D
        order = res.order["box"][i]
        at = int(np.flatnonzero(order == j)[0])
        assert not res.feasible[i, order[:at]].any()  # every earlier try of BOX failed
        assert first_feasible(res, i).constraint == j
        caption = f"instance {i}: the first feasible plan BOX finds, constraint {j} at try " \
                  f"{at + 1} (feasible, path length"
        assert caption in md and "DIFFERS FROM D" not in md
        rows.append(i)
    solved = [i for i in np.flatnonzero(res.eligible) if first_feasible(res, int(i))]
    assert rows == solved[:3]  # the first instances in row order, not picked


def test_first_feasible_is_none_when_box_s_tries_hold_none(made):
    res = load(made[0])
    row = int(np.flatnonzero(res.eligible)[0])
    feasible = res.feasible.copy()
    feasible[row] = False
    assert first_feasible(dataclasses.replace(res, feasible=feasible), row) is None


def test_first_feasible_skips_the_padding_after_the_last_try(made):
    """Layout 4 pads an order with -1 after its last try: -1 is no try (not the last
    column, which numpy's indexing would read)."""
    res = load(made[0])
    row = int(np.flatnonzero(res.eligible)[0])
    m = res.feasible.shape[1]
    feasible = res.feasible.copy()
    feasible[row] = False
    feasible[row, m - 1] = True
    order = {name: o.copy() for name, o in res.order.items()}
    order["box"][row] = -1
    order["box"][row, :2] = [0, 1]
    padded = dataclasses.replace(res, feasible=feasible, order=order)
    assert first_feasible(padded, row) is None
    order["box"][row, 2] = m - 1
    assert first_feasible(padded, row).tried == (0, 1, m - 1)
