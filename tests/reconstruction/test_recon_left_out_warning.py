"""The frame's warning when labelling leaves the junctions out (`pipeline.left_out_warning`): it names the main
reason, and for ambiguity on a rig whose labelling margin is small it gives the margin's fix. Seen on an unseen
tabletop variant (pitch 26, 53°/138°): 805 junctions, all ambiguous, margin 0.11 px, and before only "could not
label any of them". Since decision 0130 a margin of 0.11 px is "ill-posed" (under the 0.15 px a runner-up must miss
by): the marginal rig here is one of 0.3 px."""

from __future__ import annotations

from reconstruction.pipeline import few_junctions_warning, left_out_warning
from reconstruction.placement import LabellingMargin

_MARGINAL = LabellingMargin(0.3, (1, -1), 785.0)
_ILL = LabellingMargin(0.02, (0, 1), 813.0)
_GOOD = LabellingMargin(2.5, (1, 0), 900.0)


def test_nothing_labelled_names_the_main_reason_and_the_marginal_rig_fix():
    w = left_out_warning(805, 0, {"ambiguous": 805, "component_too_small": 0}, _MARGINAL)
    assert w.startswith("found 805 junctions but could not label any of them: 805 ambiguous")
    assert "label offset (1, -1)" in w and "depth range" in w and "debruijn" in w


def test_the_reason_that_left_out_most_junctions_is_named():
    w = left_out_warning(40, 0, {"ambiguous": 5, "component_too_small": 35}, _MARGINAL)
    assert "35 component too small (too few connected junctions" in w
    assert "label offset (1, -1)" not in w  # the margin is not the cause here


def test_an_ill_posed_rig_points_to_its_own_warning_instead_of_repeating_it():
    w = left_out_warning(2, 0, {"ambiguous": 1, "no_admissible_offset": 1}, _ILL)
    assert "ambiguous" in w and "ill-posed (next warning)" in w and "move the camera" not in w


def test_most_junctions_ambiguous_warns_even_when_some_are_labelled():
    w = left_out_warning(1000, 300, {"ambiguous": 700}, _MARGINAL)
    assert w.startswith("700 of 1000 junctions were left out as ambiguous") and "label offset (1, -1)" in w
    assert left_out_warning(1000, 700, {"ambiguous": 300}, _MARGINAL) is None
    assert left_out_warning(1000, 900, {"ambiguous": 100}, _GOOD) is None
    # a good margin gives no advice: the reason stands alone
    assert "depth range" not in left_out_warning(10, 0, {"ambiguous": 10}, _GOOD)


def test_many_samples_and_few_junctions_warn_about_crossings_not_found():
    # the unseen scene: 18 378 samples, 5 junctions, junction step 13.5 px, full-resolution sampling
    w = few_junctions_warning(18378, 5, 13.5, 1)
    assert w.startswith("found 18378 line samples but only 5 junctions") and "coarser pitch" in w
    # the benchmark scenes: 1.6-2.6 times the expected samples per junction
    assert few_junctions_warning(30946, 729, 13.0, 1) is None
    assert few_junctions_warning(4153, 26, 63.0, 2) is None
    # too few samples to say anything
    assert few_junctions_warning(900, 1, 13.5, 1) is None
