"""The fleet report's plots and record pages read without the code (issue 51): every mark of a
trend plot in its legend, both axes titled, each night's date on the time axis; the page of the
night a drift began says what was flagged and links back to its axis."""
from hil.fleet.report import _record_page, trend_svg

DATES = ["2026-03-02", "2026-03-09", "2026-03-16", "2026-03-23", "2026-03-30"]
PARAM = {"values": [0.5, 0.49, 0.51, 0.9, 2.2], "stderr": [0.01] * 5, "lower": [0.45] * 5, "upper": [0.55] * 5,
         "centre": 0.5, "status": ["baseline"] * 3 + ["out", "out"], "first_moved": "2026-03-23",
         "threshold_value": 1.5, "threshold": "coulomb_friction.level > 1.5 N m"}


def test_every_mark_of_a_trend_plot_is_in_its_legend_and_the_axes_are_titled():
    svg = trend_svg("coulomb_friction.level", DATES, PARAM, "torque")
    for text in ("control band (centre +- 3 sigma)", "centre (the baseline)", "value +- standard error",
                 "threshold", "first moved", "date of the record (night)", "coulomb_friction.level [N*m]"):
        assert text in svg, text
    assert all(d in svg for d in DATES)
    assert svg.count("<title>2026-") == 5            # one titled point per night


def test_the_record_page_of_the_night_a_drift_began_names_the_flag_and_links_back():
    axis = {"axis": "B", "dates": DATES, "params": {"coulomb_friction.level": PARAM},
            "flags": [{"parameter": "coulomb_friction.level", "since": "2026-03-23", "reason": "left its control limits",
                       "from": 0.5, "to": 2.2}]}
    entry = {"axis": "B", "timestamp": "2026-03-23", "record": "B_2026-03-23.csv"}
    fig = {"verdict": "coulomb_friction", "end": "noise floor reached", "named": ["coulomb_friction"], "chain": []}
    page = _record_page(entry, fig, {"coulomb_friction.level": "torque"}, axis)
    assert 'href="../report.html#axis-B"' in page
    assert "flagged this night: coulomb_friction.level left its control limits: 0.5 N m -&gt; 2.2 N m" in page
    quiet = _record_page(dict(entry, timestamp="2026-03-09"), fig, {}, axis)
    assert "nothing flagged this night" in quiet
