"""Issue 27: marker spheres on any reference body, and the IPC on the bone and nowhere else, over a family of random
reference-body CTs (``simulation.reference_ct_family``: spheres from plastic to metal, posts, frames and brackets of
any HU and thickness, joined to the bone or not, any orientation, 0.3-1 mm voxels, three partial-volume models,
noise, blur, streaks, fields of view that cut spheres). Each CT is scored against its generator's truth."""

import re

import numpy as np
import pytest

from RAMSICPRegistrationLib.commands import main
from RAMSICPRegistrationLib.image.ct_pipeline import NoBoneSurface, process_ct
from RAMSICPRegistrationLib.image.volume_io import CTVolume, save_nrrd
from RAMSICPRegistrationLib.io.marker_files import read_markers
from RAMSICPRegistrationLib.io.ndi_tools import tool_marker_geometry
from RAMSICPRegistrationLib.simulation.ct_painting import ReferenceBodyModel
from RAMSICPRegistrationLib.simulation.reference_body_phantom import (
    SHAFT_RADIUS_MM,
    SOFT_TISSUE_MM,
    make_reference_body_phantom,
)
from RAMSICPRegistrationLib.simulation.reference_ct_family import (
    BRACKET_CAP,
    WIDE_BRACKET_CAP,
    FamilyTruth,
    FieldOfView,
    make_family_ct,
    score_image_side,
    thick_bar_overrides,
    wide_bracket_overrides,
)
from RAMSICPRegistrationLib.simulation.solids import Capsule

#: The first seeds of the family (not chosen).
SEEDS = range(24)


def run(volume, truth):
    """(ImageSideResult or None, FamilyScore) of the image side on a family CT."""
    try:
        image = process_ct(volume, tool_markers=tool_marker_geometry(truth.tool_id))
    except NoBoneSurface as error:  # no IPC; the marker spheres found are given all the same
        return None, score_image_side(volume, truth, None, str(error), error.usable)
    except ValueError as error:
        return None, score_image_side(volume, truth, None, str(error))
    return image, score_image_side(volume, truth, image)


@pytest.fixture(scope="module")
def family():
    """{seed: (truth, ImageSideResult or None, FamilyScore)} over SEEDS, made once."""
    scored = {}
    for seed in SEEDS:
        volume, truth = make_family_ct(seed)
        image, score = run(volume, truth)
        scored[seed] = (truth, image, score)
    return scored


def test_no_usable_sphere_is_false_and_no_cut_sphere_is_usable(family):
    """Issue 27: no false sphere among those marked usable; spheres cut by the field of view flagged."""
    for seed, (truth, image, score) in family.items():
        assert score.false == 0 and score.cut_usable == 0, seed
        for sphere in image.spheres if image else ():
            if sphere.number and truth.marker_states[sphere.number - 1] == "cut":
                assert sphere.status == "partial" and "cut by the edge of the field of view" in sphere.note


def test_visible_spheres_are_found_to_0_15_mm_with_their_numbers(family):
    visible = sum(score.visible for _, _, score in family.values())
    found = sum(score.found for _, _, score in family.values())
    assert visible > 60 and found >= 0.97 * visible


def test_the_ipc_is_the_bone_not_the_reference_body(family):
    """Over the seeds: at least 99 % of the IPC within 0.5 mm of the true bone surface (issue 27's target; the
    benchmark gives the figure over 200 seeds), and on most CTs no IPC point on the body or its bracket."""
    scores = [score for _, _, score in family.values()]
    assert sum(bool(score.refused) for score in scores) <= 1
    points = sum(score.ipc_points for score in scores)
    assert sum(score.ipc_on_bone for score in scores) >= 0.99 * points
    assert sum(score.ipc_on_body == 0 for score in scores) >= 0.75 * len(scores)
    assert np.median([score.coverage for score in scores if not score.refused]) >= 0.9


#: CTs of the family (quick profile) the 200-seed benchmark found the IPC wrong on, each for one reason, with the
#: share of the IPC within 0.5 mm of the bone before the fix: the round field of view (reconstruction cylinder)
#: opening the marrow (7: 93 %, 21: 55 %, 32: 54 %), a steel pin through the bone taken for its cortex and the
#: surface level set too high (81: 0 %), cancellous bone between the surface level and the threshold wiped with the
#: specks in it (57: 93 %), a plastic body with its spheres sunk into a plate taken for a bone without a cortex (107:
#: the whole IPC on the body).
HARD_SEEDS = (7, 21, 32, 57, 81, 107)


@pytest.mark.parametrize("seed", HARD_SEEDS)
def test_the_ipc_on_ct_that_defeated_it(seed):
    volume, truth = make_family_ct(seed)
    _, score = run(volume, truth)
    assert not score.refused and score.coverage > 0.6
    assert score.ipc_on_bone >= (0.96 if seed == 81 else 0.99) * score.ipc_points  # 81: its bracket's stub
    assert score.ipc_on_body <= 0.04 * score.ipc_points


#: Full-profile CTs from the benchmark's runs on fresh seeds that the image side got wrong, each for one reason, with
#: what it gave before the fix: a tibia the field of view cuts obliquely, its marrow open to the CT's
#: side, too thin without it to be bone, joined to the body by a metal bracket (1060: refused, 4 visible spheres
#: lost); a body whose spheres are out of view or sunk into its bright frame, joined to the bone by an inserted metal
#: bracket (3044: 0.7 % of the IPC on the bone, the rest on the body); a dim bracket (170 HU, under the threshold)
#: inserted into a long bone, its hole opening the marrow (3000: 55 %, the marrow's wall in the IPC); a bright ring
#: frame joined to a long bone by a bracket just above the threshold, which the spheres' own seeds did not reach
#: (6082: 55 %, 19,474 IPC points on the frame); a metal star frame (2,400 HU) on a bracket of 1,470 HU in a fibula,
#: whose side of the cut looked like bone (a bright rim round the bracket's dimmer core: 9171, 35 %, 7,345 points
#: on the body); dim posts and frame under bright spheres, their start lost in the spheres' blurred rim, so that the
#: metal bracket (2,380 HU) stayed on the tibia and set its surface level (9199: 0.8 %); surface levels read round
#: the bone off where the surface is: a 3 mm layer of soft tissue with air beyond it (11137: 0.8 mm out, 0 % within
#: 0.5 mm; 11168: a dim cortex of 706 HU under 3.3 mm, 0.6 mm out, 3 %), a round field of view padded at
#: -3024 HU in the band round the bone (11052: 2.7 mm out, 0 %).
FULL_PROFILE_HARD = {
    1060: 0.95,
    3044: 0.99,
    3000: 0.99,
    6082: 0.99,
    9171: 0.99,
    9199: 0.99,
    11052: 0.99,
    11137: 0.99,
    11168: 0.99,
    12042: 0.99,  # an ilium's wall behind the hole of a dim 4.8 mm bracket (87 % before the bone's envelope)
    12066: 0.99,  # a flat bone whose cancellous core is above the threshold, a metal bracket resting on it (refused)
    12190: 0.99,  # a tibia's marrow wall behind the hole of a dim 9 mm bracket (79 % before the bone's envelope)
    13116: 0.99,  # a metal plate round a pocket of air the round field of view closes: its "cortex" outranked the bone
}


@pytest.mark.parametrize("seed", sorted(FULL_PROFILE_HARD))
def test_the_ipc_on_full_profile_ct_that_defeated_it(seed):
    volume, truth = make_family_ct(seed, "full")
    _, score = run(volume, truth)
    assert not score.refused and score.found == score.visible
    assert score.coverage > (0.75 if seed == 9171 else 0.8)  # 9171: a short fibula, 5.7 mm round the bracket left out
    assert score.ipc_on_bone >= FULL_PROFILE_HARD[seed] * score.ipc_points
    assert score.ipc_on_body <= 0.02 * score.ipc_points


@pytest.mark.parametrize("seed", [12138, 12177])
def test_a_dim_bracket_fixed_into_a_bone_in_air_leaves_no_stub_in_the_ipc(seed):
    """A plastic bracket (186 and 120 HU) inserted into a bone in air: the surface level (half-max, -25 and -121 HU)
    is below the bracket, which is below the threshold (200 HU); the two voxels of it kept round the bone made a stub
    of 275 and 212 IPC points on the bracket (1.5 and 0.6 % of the IPC). At most 0.1 % now."""
    volume, truth = make_family_ct(seed, "full")
    _, score = run(volume, truth)
    assert score.ipc_on_body <= 0.001 * score.ipc_points
    assert score.ipc_on_bone >= 0.999 * score.ipc_points and score.coverage > 0.95


@pytest.mark.parametrize("seed", [19027, 19077])
def test_a_dim_bracket_resting_on_the_bone_adds_no_surface_without_a_cortex(seed):
    """19027: a 6 mm bracket of 271 HU resting on a fibula in air, its reference body out of view (no sphere to tell
    it by): the surface level (half-max, 251 HU) is below the bracket, and 1,287 IPC points lay on it, 1 mm inside.
    19077: a 202 HU bracket's stub on a flat bone in air, at a 63 HU level: 103 points 8-10 mm off the bone. Under
    them the CT rises above the level by less than a fifth of the level's own rise over the air (the bracket's HU is
    the level's, near enough), where a cortex rises as high again. 27 and 9 points are left: the corner the blur
    fills where the bracket meets the bone (0.5-0.9 mm off it), and small pieces of surface round noise holes inside
    the bracket or cut off on the stub, whose own rise is not the bracket's."""
    volume, truth = make_family_ct(seed, "full")
    _, score = run(volume, truth)
    assert score.ipc_on_body <= 0.0025 * score.ipc_points  # 0.21 and 0.02 % measured
    assert score.ipc_on_bone >= 0.997 * score.ipc_points and score.coverage > 0.95  # 96.3 and 95.7 %, as before


def test_a_level_read_off_a_rim_brighter_than_the_cortex_leaves_the_bone_in_the_ipc():
    """Family seed 13023: a metal bracket (1,790 HU) inserted into a long bone whose cortex is 964 HU. The level read
    round the bone (770 HU) takes the bracket's rim for the cortex, and lies near the top of every point's rise: the
    bone's whole surface looks like a part without a cortex, and the first form of that rule left 1 IPC point of
    5,153. It waits for the level read across the surface (496 HU), where the cortex's rise is twice the level's."""
    volume, truth = make_family_ct(13023, "full")
    _, score = run(volume, truth)
    assert score.ipc_points > 5000 and score.ipc_on_bone == score.ipc_points
    assert score.coverage > 0.95  # 95.5 %, as before


def test_spheres_sunk_into_a_brighter_plate_still_say_where_the_body_is():
    """Spheres of 690 HU sunk into a 5 mm plate of 1,900 HU (the generator calls all four hidden), the plate joined to
    a tibia by a metal bracket: no sphere fits, so nothing said where the body was, and the IPC was the plate's
    (45,355 of its 54,154 points). Where the body is a ball thick (``image.thick_spots``) and the tool's distances
    pair four such spots, the body is cut off: no IPC point on it."""
    volume, truth = make_family_ct(14087, "full")
    _, score = run(volume, truth)
    assert not score.refused and score.ipc_on_body == 0 and score.ipc_on_bone >= 0.99 * score.ipc_points


def test_a_dim_frame_split_by_specks_above_the_threshold_still_leads_to_its_bracket():
    """Plastic spheres (165 HU), posts and a ring frame (185 HU) all below the threshold, with noise specks above it
    that split the frame's dim parts, and a 303 HU bracket inserted into a flat bone: the dim parts from the spheres
    reached the specks but not the bracket, which stayed on the bone (2,916 IPC points on it). The dim parts start
    from the objects the posts stand on too now. (When a solid part the bone's core grows was first set apart, a piece
    of the frame here, 2 points 0.5-0.9 mm off the bone lay on the bracket's foot, until the holes that noise leaves
    in it were no longer taken for marrow.)"""
    volume, truth = make_family_ct(14053, "full")
    _, score = run(volume, truth)
    assert score.found == score.visible == 4 and score.ipc_on_body == 0
    assert score.ipc_on_bone >= 0.999 * score.ipc_points and score.coverage > 0.9


@pytest.mark.parametrize("seed", [15036, 15065])
def test_a_flat_bone_whose_inside_is_nearly_as_bright_as_its_cortex_is_cut_off_its_bracket(seed):
    """Flat bones whose cancellous inside (486 and 576 HU) is nearly as bright as their cortex (719 and 741 HU): a rim
    of +112 and +89 HU, under the +150 HU that makes a cortex. Cut off the bracket, the bone's part was no cortex and
    the cut was dropped (15065: 1,341 IPC points on a 1,125 HU bracket); where the cut stood, each piece growing out of
    the bone looked like a rod (no cortex either) and was set apart (15036: 8 % of the bone kept). A part cut off whose
    rim is brighter than a solid part's is bone (when no object has a cortex), and a piece whose rim is four fifths of
    the bone's own is the bone going on."""
    volume, truth = make_family_ct(seed, "full")
    _, score = run(volume, truth)
    assert score.ipc_on_body == 0 and score.ipc_on_bone >= 0.999 * score.ipc_points and score.coverage > 0.9


def test_a_bone_whose_object_closes_round_air_is_bone_still_when_no_other_is():
    """A flat bone with a metal bracket resting on it and a star frame: the loop they make closes round air, so the
    object's filled inside is air (seed 13019); with no other object round marrow it is the bone all the same (the
    rule first tried for 13116, that a rim round air is no cortex at all, refused this CT)."""
    volume, truth = make_family_ct(13019, "full")
    _, score = run(volume, truth)
    assert not score.refused and score.ipc_on_bone >= 0.99 * score.ipc_points and score.found == score.visible


def test_spheres_sunk_into_a_frame_as_wide_as_they_are_are_not_given_off_centre():
    """Spheres of 2,030 HU sunk into a star frame of 260 HU whose arms (11.3 mm) are as wide as they are (the generator
    calls them hidden): the thin layer of frame over their rim moved its rays' edges out, and the centres 0.15-0.20
    mm, with an RMS of 0.105 mm. The rays whose profile lingers past the edge are left out: every sphere given usable
    is within 0.15 mm."""
    volume, truth = make_family_ct(10135, "full")
    image, score = run(volume, truth)
    assert score.false == 0 and len(image.usable) >= 3


def test_a_sphere_larger_than_the_nominal_with_a_rough_edge_is_not_given_usable():
    """Fresh wide seed 58026 at 62 HU of noise: plastic spheres of 131 HU on 7.8 mm posts of 2,851 HU, two of the four
    damaged. The other two, seen over 92.5 %, were fitted 0.04 and 0.06 mm larger than the nominal with an RMS of 0.15
    and 0.14 mm, and given usable 0.37 and 0.29 mm off their markers. A blurred ball's half-max edge lies inside its
    surface: larger with a rough edge, a sphere is now partial, numbered still."""
    volume, truth = make_family_ct(58026, "full", overrides={**wide_bracket_overrides(58026), "noise_hu": 62.0})
    image, score = run(volume, truth)
    assert score.false == 0 and not image.usable
    pushed = [sphere for sphere in image.spheres if sphere.number in (2, 4)]
    assert [sphere.status for sphere in pushed] == ["partial", "partial"]
    assert all(sphere.radius_mm > 5.75 and "pushes this one's out" in sphere.note for sphere in pushed)


def test_the_papers_set_up_a_bracket_joins_a_body_larger_and_brighter_than_the_piece_of_bone():
    """The CT the old detector found 0 of 4 spheres in: spheres of 800 HU on posts and a frame of 1000 HU, bone at
    1300 HU, a 6 mm bracket of 1000 HU inserted into a flat bone (the paper's ilium) of which the field of view holds
    only a short piece, so that bone, bracket and body are one object above the threshold, larger than the bone."""
    overrides = {
        "bone": "flat",
        "cortex_hu": 1300.0,
        "sphere_hu": 800.0,
        "post_hu": 1000.0,
        "frame_hu": 1000.0,
        "bracket": "inserted",
        "bracket_hu": 1000.0,
        "bracket_diameter_mm": 6.0,
        "bone_reach_mm": 10.0,
        "cut_markers": [],
        "post_length_mm": 15.0,
        "damaged": [],
    }
    volume, truth = make_family_ct(4, overrides=overrides)
    image, score = run(volume, truth)
    assert score.found == score.visible == 4 and score.false == 0
    assert score.ipc_on_bone >= 0.99 * score.ipc_points and score.ipc_on_body == 0 and score.coverage > 0.9
    segmentation = image.segmentation
    joined = segmentation.labels == segmentation.bone_label
    body = segmentation.body
    assert body is not None and body.sum() > 0.2 * joined.sum()  # one object, a good part of it the body's
    # The spheres are the body's part of the joined object (their voxels relabelled apart afterwards).
    assert all(
        body[tuple(np.rint(volume.ras_to_ijk_points(c[None])[0]).astype(int) - segmentation.origin)]
        for c in truth.marker_centres
    )


def test_plastic_spheres_below_the_bone_threshold_are_found():
    overrides = {"sphere_hu": 110.0, "post_hu": 110.0, "frame_hu": 110.0, "cut_markers": [], "damaged": []}
    volume, truth = make_family_ct(7, overrides=overrides)
    image, score = run(volume, truth)
    assert score.visible >= 3 and score.found == score.visible and score.false == 0
    assert all(sphere.label == 0 or sphere.status == "ok" for sphere in image.usable)


@pytest.mark.parametrize("seed", [14013, 15072])
def test_the_stub_of_a_bracket_inserted_into_a_thin_bone_is_left_out_along_its_line(seed):
    """Brackets as bright as the cortex inserted into fibulas (full profile): the stub the cut left on the bone, 6-17
    mm long, joined the bone's own thin parts and was kept (439 and 185 IPC points on it); along the bracket's line
    (``bracket_stub.BracketLine``) it is left out."""
    volume, truth = make_family_ct(seed, "full")
    _, score = run(volume, truth)
    assert not score.refused and score.ipc_on_body == 0 and score.ipc_on_bone >= 0.99 * score.ipc_points
    assert score.coverage >= 0.78  # 80 and 81 % measured, as before the line (what else is left out is not its)


@pytest.mark.parametrize("seed", [15028, 12023])
def test_the_line_of_a_bracket_is_read_beyond_the_bone_box_and_on_the_side_it_comes_from(seed):
    """15028: a 10.9 mm bracket inserted into an 18 mm tibia; the box round the bone cut its end to a disc, wider
    than long, that gave no line (354 IPC points on the stub, 3-7 mm off the bone). 12023: a 6.5 mm bracket through
    an 11 mm flat bone, its tip out of the far side next to the bone too, so the end's axis was no line (149 points
    on the tip); the line is read on the end's largest piece."""
    volume, truth = make_family_ct(seed, "full")
    _, score = run(volume, truth)
    assert not score.refused and score.ipc_on_body == 0 and score.ipc_on_bone == score.ipc_points
    # 82.5 and 91 % measured. 15028 covered 86 % until the bracket was cut off as a rod (a cavity beside it is no
    # marrow, test_a_cavity_beside_a_bracket_is_no_marrow_of_it): the margin round a rod is the opening that cut it.
    assert score.coverage >= (0.80 if seed == 15028 else 0.88)


@pytest.mark.parametrize("seed, covered", [(15093, 0.97), (19041, 0.82), (13086, 0.96), (26033, 0.91)])
def test_the_tip_of_a_bracket_through_the_bone_is_left_out_past_a_plate_near_it_or_aslant(seed, covered):
    """Brackets inserted through the bone, their tips out of its far side (``bracket_stub.BracketLine``). 15093: a
    4.7 mm bracket of 871 HU through an 8 mm flat bone, its 338 HU plate within 11 mm of the bone beside it, and
    19041: a 6 mm bracket through a fibula, its plate within 9 mm: the body's end took in the plate, its axis lay
    across it and gave no line (247 and 37 IPC points on the tip). 13086: a 6.5 mm bracket of 1,340 HU whose round
    tip comes out of an 11 mm flat bone aslant, the ring round it in the bone to the end of its run (84). 26033: a 7.9
    mm bracket through a tibia aslant, the line read on its end 6.7 degrees off (48). None now."""
    volume, truth = make_family_ct(seed, "full")
    _, score = run(volume, truth)
    assert not score.refused and score.ipc_on_body == 0 and score.ipc_on_bone == score.ipc_points
    assert score.coverage >= covered  # 98.2, 84.0, 97.1 and 93.1 % measured


def test_a_plate_within_the_end_of_a_bracket_does_not_hide_its_line():
    """Family seed 18070 (full profile): a 7.5 mm bracket inserted into a tibia from an 11.4 mm plate whose face lies
    within the 8 mm of the bracket's end that its line is read over. The plate, deeper than the bracket, gave the end a
    radius of 6 mm and no line: 490 of 33,196 IPC points lay on the bracket's stub, 4-9 mm off the bone, with exit 0.
    The bracket's radius is read where its depth stops growing away from the bone now, and the plate is opened off
    its end: none."""
    volume, truth = make_family_ct(18070, "full")
    _, score = run(volume, truth)
    assert not score.refused and score.ipc_on_body == 0 and score.ipc_on_bone == score.ipc_points
    assert score.coverage >= 0.95  # 96.4 % measured, as before


@pytest.mark.parametrize("seed", [16088, 14020])
def test_a_wire_or_thin_rod_joined_to_the_bone_leaves_no_ipc_off_it(seed):
    """Full profile. 16088: a wire (300-3,071 HU, 0.6-2.4 mm wide in the family) touching a tibia: its surface was
    the IPC's, 669 points 32 mm off the bone on average (96.0 % of the IPC on the bone). 14020: a 715 HU bracket 6.7
    mm wide resting on a tibia, the rest of the body out of view or below the threshold: 1,236 points on it (95.8 %).
    Both are left out as the line they are (``thin_appendages.wires_on_bone``), the bone's coverage as before (96.8
    and 99.0 %)."""
    volume, truth = make_family_ct(seed, "full")
    _, score = run(volume, truth)
    assert not score.refused and score.ipc_on_body == 0
    assert score.ipc_on_bone >= 0.999 * score.ipc_points and score.coverage >= 0.96


def test_a_wire_off_a_bone_the_opening_takes_whole_leaves_no_ipc_off_it():
    """Wide seed 40258: a fibula 8 mm thick in air, a 750 HU wire from it to the field of view's edge. On cells of
    0.86 mm the wire's opening (a cube 6 mm wide) took the fibula whole with the wire, so no line was left to find:
    770 of 5,126 IPC points lay on the wire, up to 51 mm off the bone (84.4 % on the bone), with exit 0. A narrower
    opening keeps the fibula and takes the wire: 4,288 of 4,312 on the bone (the other 24, 0.7-2.1 mm off it 10-13 mm
    from a steel pin, were off it before too), none on the body, 81.9 % of the bone covered (82.4 % before)."""
    volume, truth = make_family_ct(40258, "full", overrides=wide_bracket_overrides(40258))
    _, score = run(volume, truth)
    assert not score.refused and score.ipc_on_body == 0
    assert score.ipc_on_bone >= 0.99 * score.ipc_points and score.coverage >= 0.8


def test_a_frame_solid_through_is_not_taken_for_a_bone_without_a_cortex():
    """Family seed 16078 (full profile): a tibia's end wholly outside the round field of view, the reference body's
    star frame, posts and bracket of 707 HU in it (3 of its spheres cut). No object has a cortex; the frame, 10 mm
    thick, has a rim 172 HU dimmer than its inside, and one sphere is found. It was taken for a bone without a cortex:
    the IPC was the frame's (7,542 points, none on the bone), with exit 0. Now the CT is refused, rightly (no bone in
    view)."""
    volume, truth = make_family_ct(16078, "full")
    image, score = run(volume, truth)
    assert image is None and score.rightly_refused and score.bone_in_view_mm3 == 0.0
    assert "no object in the CT has a cortex, and the one taken for bone" in score.refused
    assert "is solid, beside 1 marker sphere(s) found" in score.refused


def test_a_frame_dimmer_on_its_rim_than_inside_is_not_taken_for_bone_when_no_sphere_is_found():
    """Family seed 40133 with wide brackets: plastic spheres (139 HU) sunk into a 1,369 HU plate, a 9 mm square bar of
    2,495 HU resting on a fibula of which 0.9 cm^3 is in view. No sphere is found and no object has a cortex; the
    plate and bar, rim 22 HU dimmer than their inside, were taken for a bone without a cortex: the IPC was the
    plate's (29,749 points, none on the bone), exit 0. Now the CT is refused, rightly (under 1.5 cm^3 of bone)."""
    volume, truth = make_family_ct(40133, "full", overrides=wide_bracket_overrides(40133))
    image, score = run(volume, truth)
    assert image is None and score.rightly_refused and score.bone_in_view_mm3 < 1000.0
    assert "is solid, dimmer on its rim than inside, which no bone is, and no marker sphere was found" in score.refused


def test_spheres_sunk_into_a_brighter_plate_found_by_their_caps_in_the_ipc_refuse_it():
    """Family seed 40192 with wide brackets: two 1,037 HU spheres sunk into a 7.7 mm plate of 1,381 HU (their caps
    1.9 mm high on both sides), two more cut by the field of view, a 15.4 mm bar of 816 HU inserted into a tibia 17 mm
    thick. No sphere is found and none is tied (no edge of their own, no spot a ball thick in a plate nearly as
    thick): the plate was taken for bone and the IPC was its surface (23,454 of 23,688 points on the body), exit 0.
    The IPC itself holds three balls of the marker's size at the tool's distances: it is refused, with their centres
    (within 0.5 mm of the true ones). 2.7 cm^3 of the tibia is in view, so the benchmark counts the refusal a miss."""
    volume, truth = make_family_ct(40192, "full", overrides=wide_bracket_overrides(40192))
    image, score = run(volume, truth)
    assert image is None and score.ipc_on_body == 0
    assert "no marker sphere was found, but the surface taken for the bone holds 3 balls" in score.refused
    centres = np.array(re.findall(r"\((-?\d+), (-?\d+), (-?\d+)\) mm", score.refused), float)
    assert len(centres) == 3
    for centre in centres:
        assert np.linalg.norm(truth.marker_centres - centre, axis=1).min() < 1.0  # printed to the mm


@pytest.mark.parametrize("seed, covered", [(40245, 0.85), (40248, 0.95)])
def test_a_bracket_nearly_as_thick_as_the_bone_is_followed_by_its_material(seed, covered):
    """Wide seeds 40245 (a 15.8 mm bar of 670 HU resting on a flat bone 17.6 mm thick, cortex 849 HU, inside 508 HU)
    and 40248 (a 384 HU star frame on a 17.9 mm rod of 2,096 HU inserted into a flat bone 19.9 mm thick). No opening
    parts a bracket 0.9 of the bone's thickness from it: the cut kept the bar, or the rod and the frame's end, with the
    bone, and the IPC had 6,856 and 3,402 points on them (40248's was the rod's: none of the bone covered), exit 0.
    The body is now followed by its material into what the cut kept: the bar's plateau (670 HU), the frame's (384 HU)
    and then the rod's (2,098 HU). Measured: no point on the body, 88.5 % and 95.8 % of the bone covered."""
    volume, truth = make_family_ct(seed, "full", overrides=wide_bracket_overrides(seed))
    image, score = run(volume, truth)
    assert not score.refused and score.ipc_on_body == 0 and score.ipc_on_bone == score.ipc_points
    assert score.coverage >= covered
    assert image.segmentation.body_followed.any()


def test_a_bracket_nearly_as_thick_as_the_bone_is_followed_under_heavy_noise():
    """Wide seed 40279 drawn as the held-out wide CT 3009 was: 62 HU of noise, a 19.3 mm square bar of 956 HU from a
    1,794 HU frame, inserted into a long bone 30.8 mm thick. No level is read from the block means under that noise,
    so nothing was followed and 3,732 IPC points lay on the body (3009: 245), exit 0. The levels are read from the
    averaged means now: the frame's plateau (1,787 HU), then the bar's (952 HU). Measured: none on the body, 85.2 % of
    the bone covered (87.9 % if every plateau round a cavity were refused as a shell: the bar's level, read a third
    time, takes 307 mm^3 more)."""
    overrides = {**wide_bracket_overrides(40279), "noise_hu": 62.0, "bracket_hu": 956.0}
    volume, truth = make_family_ct(40279, "full", overrides={**overrides, "frame_hu": 1794.0, "post_hu": 1794.0})
    image, score = run(volume, truth)
    assert not score.refused and score.ipc_on_body == 0 and score.ipc_on_bone == score.ipc_points
    assert score.coverage >= 0.8
    assert image.segmentation.body_followed.any()


def test_a_bracket_as_thick_as_the_bone_is_followed_from_seeds_no_opening_parts_it_from():
    """Family seed 107 with a thick bar (``thick_bar_overrides``): a 12.1 mm square bar of 1,053 HU resting on a long
    bone 13.9 mm thick (cortex 945 HU, 9.3 HU of noise), its star frame of 186 HU below the 200 HU threshold. The dim
    parts link the spheres to the bar's far end, but no opening parts a bar that thick from the bone, so nothing was
    cut and the bar stayed with the bone: 6,800 of 14,548 IPC points on it, exit 0. The body is now followed by its
    material from its seeds where no opening parts it (the bar's plateau, 1,052 HU). Measured: 1 of 7,620 points on
    the body, all of the bone covered."""
    volume, truth = make_family_ct(107, "full", overrides=thick_bar_overrides(107))
    assert truth.settings["frame_hu"] < 200.0  # the frame is below the threshold: only the dim parts hold the bar
    image, score = run(volume, truth)
    assert not score.refused and score.ipc_on_body <= 0.001 * score.ipc_points
    assert score.ipc_on_bone >= 0.99 * score.ipc_points and score.coverage >= 0.95
    assert image.segmentation.body_followed.any()


def test_a_bar_ringed_by_its_own_blur_is_not_taken_for_the_bones_inside():
    """Wide seed 40255 drawn as 3009 was (62 HU of noise, an 18 mm square bar of 956 HU from a 1,794 HU frame,
    inserted into a long bone 21.8 mm thick). The frame's plateau was followed, then the bar's (953 HU) refused as
    the bone's inside: 92 % of the ring round it lies in the bone left, and its median (900 HU) was within 80 HU
    below the bar. That ring is the bar's own blur; a bone's inside is ringed by its cortex, brighter than it (by
    +99 HU or more over the 338 family CTs a cut reaches; the body's parts -46 HU or less). A ring darker than the
    plateau now leaves it the body's. Measured: 5,178 IPC points on the body before, 35 now (0.2 %), 95.9 % of the
    bone covered."""
    overrides = {**wide_bracket_overrides(40255), "noise_hu": 62.0, "bracket_hu": 956.0}
    volume, truth = make_family_ct(40255, "full", overrides={**overrides, "frame_hu": 1794.0, "post_hu": 1794.0})
    image, score = run(volume, truth)
    assert not score.refused and score.ipc_on_body <= 0.005 * score.ipc_points
    assert score.ipc_on_bone >= 0.99 * score.ipc_points and score.coverage >= 0.9
    assert image.segmentation.body_followed.any()


def test_a_plateau_is_solid_whatever_the_noise_lifts_its_rims_maxima_by():
    """Wide seed 41011 drawn with 62 HU of noise (its own draw: 5 HU): spheres, posts, frame and an 18 mm square bar
    all of 2,057 HU, the bar inserted into a long bone 20 mm thick, one sphere cut and one damaged. The bar's plateau
    read a rim contrast of +76 HU (the rim's cell maxima against the inside's means; a solid part is under +75), was
    refused as not solid, and 10,712 of the 22,325 IPC points lay on the body, exit 0. The contrast is now taken less
    what the noise lifts a maximum above its mean inside the plateau. Measured: none on the body, 90.9 % covered."""
    volume, truth = make_family_ct(41011, "full", overrides={**wide_bracket_overrides(41011), "noise_hu": 62.0})
    image, score = run(volume, truth)
    assert not score.refused and score.ipc_on_body == 0 and score.ipc_on_bone == score.ipc_points
    assert score.coverage >= 0.85
    assert image.segmentation.body_followed.any()


def test_a_thin_layer_of_tissue_with_air_beyond_leaves_the_surface_on_the_cortexs_edge():
    """Wide seed 41008 drawn with 62 HU of noise (its own draw: 17 HU): a right ilium's 1.8 mm cortex of 1,657 HU
    under 3.1 mm of soft tissue with air beyond. The level read round the bone took the air for what the cortex
    touches (305 HU), and the level read across the surface, half-way between the cortex's peak and what lay 1-2 mm
    beyond the points, took the air's edge again (502 HU): the IPC lay 0.42 mm out (median), 44,026 of its 56,792
    points within 0.5 mm of the bone. The level is now the CT where the cortex falls most steeply. Measured: 54,936
    of 54,975, 0.15 mm out (median), none on the body."""
    volume, truth = make_family_ct(41008, "full", overrides={**wide_bracket_overrides(41008), "noise_hu": 62.0})
    image, score = run(volume, truth)
    assert not score.refused and score.ipc_on_body == 0 and score.ipc_on_bone >= 0.995 * score.ipc_points
    signed = truth.bone.signed_distance(image.surface.points)
    assert abs(float(np.median(signed))) < 0.2  # 0.15 mm out
    assert score.coverage >= 0.85


@pytest.mark.parametrize("seed", [40272, 43049])
def test_a_wide_dim_bracket_meeting_the_bone_is_a_dim_part_whatever_its_contact(seed):
    """Wide seed 40272: an 18 mm square bracket of 138 HU inserted into a long bone in air; 43049: a 14 mm square bar
    of 136 HU resting on a long bone under 11 mm of soft tissue. Below the surface level, the first is a hole in the
    cortex whose walls make a surface 0.5-1.8 mm inside the bone, and the second's corner with the bone a surface
    0.5-0.9 mm inside it: 154 and 44 IPC points on the body. They meet the bone's blur over more than a dim part was
    allowed (40272: 1,159 mm^2; the limit was 400, against soft tissue round the bone); at 1,600 mm^2 their surface
    goes as the corner a dim part makes with the bone. Measured: none on the body, 9,496 of 9,496 and 2,737 of 2,758
    on the bone."""
    volume, truth = make_family_ct(seed, "full", overrides=wide_bracket_overrides(seed))
    _, score = run(volume, truth)
    assert not score.refused and score.ipc_on_body == 0 and score.ipc_on_bone >= 0.99 * score.ipc_points


@pytest.mark.parametrize("seed, on_bone", [(35065, 0.999), (43004, 0.97)])
def test_the_inside_a_dim_brackets_hole_joins_to_the_outside_is_plugged_where_the_bracket_meets_the_bone(seed, on_bone):
    """Family seed 35065: a 10.8 mm rod of 141 HU inserted into a tibia's metaphysis (marrow -60 HU, 30-50 mm across)
    under 23 mm of 4 HU tissue; fresh wide seed 43004: a 13.9 mm square bar of 141 HU inserted into a flat bone whose
    155 HU inside the field of view's round edge cuts beside its one table in view. Below the surface level, the
    bracket's hole joined the bone's inside to the outside: no fill found it, the envelope's closing did not plug a
    hole that wide in a bone curved or cut that close, and the marrow's wall stayed in the IPC, 1.3-2.3 mm inside the
    bone (7,259 of 29,308 and 7,303 of 17,683 IPC points), exit 0. The hole is now plugged where the bracket meets the
    bone's blur (``dim_parts``), and what the bone then encloses between its sides is its inside. Measured: 22,049 of
    22,051 and 10,380 of 10,661 on the bone (43004's 281 others lie 1.1-2.1 mm from the field of view's edge, on the
    table's inner side facing it), none on the body (25 and 29 before: 43004 keeps 21), the same share of the bone
    covered (95.0 % and 89.5 %)."""
    volume, truth = make_family_ct(seed, "full", overrides=wide_bracket_overrides(seed) if seed >= 40000 else None)
    image, score = run(volume, truth)
    assert not score.refused and score.ipc_on_bone >= on_bone * score.ipc_points
    signed = truth.bone.signed_distance(image.surface.points)
    assert np.mean(signed < -1.0) <= 1.0 - on_bone  # the marrow's wall is gone
    assert score.coverage >= 0.85 and score.ipc_on_body <= 0.002 * score.ipc_points


def test_a_bone_along_the_round_field_of_views_edge_is_not_filled_with_the_tissue_between_them():
    """Drawn family seed 48024: a flat bone 12.6 mm thick (1.5 mm of 1,165 HU cortex round a 434 HU inside, so solid
    at the threshold) under 6.7 mm of tissue, running along a round field of view's edge, a steel pin through it.
    Filled with the padding taken for the CT's side, the tissue between the bone and the padding was the object's
    inside, 27 mm thick, its rim 190 HU dimmer than it, and the bone was refused as a solid frame beside its
    spheres with 87 cm^3 of it in view. Filled without the padding, its rim is its cortex (+498 HU;
    ``bone_recognition._ObjectShape._not_walled_by_the_padding``): 16,688 IPC points, all on the bone, none on the
    body (40 % of the bone in view covered: the pin's surroundings and the field of view's edge are left out)."""
    volume, truth = make_family_ct(48024, "full")
    _, score = run(volume, truth)
    assert not score.refused and score.ipc_points > 10000
    assert score.ipc_on_bone == score.ipc_points and score.ipc_on_body == 0 and score.coverage >= 0.35


def test_a_thin_bone_that_coarse_cells_cannot_cut_off_its_bar_is_cut_on_finer_ones():
    """Wide family seed 40193: an 8.4 mm square bar of 2,352 HU resting on a flat bone 9.7 mm thick (2 mm of 1,992 HU
    cortex round 504 HU), joining it to an 11.2 mm plate of 1,736 HU: one object of 189 cm^3, measured on cells of
    1.4 x 1.4 x 1.8 mm (``bone_recognition.MAX_CELLS``), where no opening lies between the bar's half width and the
    bone's half thickness, and the CT was refused with 60 cm^3 of bone in view. Refused so, the image side looks once
    more on grids of FINE_MAX_CELLS (its voxels, 0.7 x 0.7 x 0.9 mm): 37,117 IPC points, all on the bone, 95.8 % of
    it covered."""
    volume, truth = make_family_ct(40193, "full", overrides=wide_bracket_overrides(40193))
    _, score = run(volume, truth)
    assert not score.refused and score.ipc_points > 30000
    assert score.ipc_on_bone == score.ipc_points and score.ipc_on_body == 0 and score.coverage >= 0.9


def test_a_loose_spot_at_the_tools_distances_numbers_no_sphere_of_a_cut_reference_body():
    """Fresh wide family seed 47003: markers 1 and 4 cut by the field of view, 2 damaged, 3 whole. A spot at the
    field of view's edge (0.57 mm RMS off its ball) lay where marker 1 would be were markers 2 and 3 the other way
    round; the tool's distances paired the three to 1.05 mm (FRE), and the clean sphere, marker 3, was numbered 2:
    a usable sphere 55.9 mm from its marker. Now no sphere is numbered (``marker_spheres.LOOSE_PAIRING_FRE_MM``),
    and the IPC is the bone's as before (24,689 points)."""
    volume, truth = make_family_ct(47003, "full", overrides=wide_bracket_overrides(47003))
    image, score = run(volume, truth)
    assert score.false == 0 and not image.usable and image.pairing is None
    assert not score.refused and score.ipc_on_bone == score.ipc_points > 20000


def test_a_flat_bone_whose_inside_a_dim_brackets_hole_opens_is_not_refused_as_a_solid_frame():
    """Wide seed 40232: a 116 HU bracket 9.3 mm wide inserted into a flat bone 10.3 mm thick (1.1 mm of 1,389 HU
    cortex round a 163 HU inside), aslant the grid and cut by the CT's box on five sides, its plastic spheres (116 HU)
    found but two of them partial. Below the threshold, the inside was one region with the tissue through the
    bracket's hole: the bone was its two tables to the fill, its rim no brighter than its inside, and it was refused
    as the body's solid frame beside its spheres, with 115 cm^3 of bone in view. Its holes plugged, it encloses its
    inside (``bone_recognition._ObjectShape._plugged``): 48,038 of its 48,040 IPC points on the bone, 2 on the body
    (where the bracket meets it), 94.8 % of the bone in view covered."""
    volume, truth = make_family_ct(40232, "full", overrides=wide_bracket_overrides(40232))
    _, score = run(volume, truth)
    assert not score.refused and score.ipc_points > 40000
    assert score.ipc_on_bone >= 0.999 * score.ipc_points and score.ipc_on_body <= 5 and score.coverage >= 0.9


def test_a_long_bone_whose_marrow_a_wide_dim_brackets_hole_opens_is_plugged_wider():
    """Fresh wide seed 51017: a 10.9 mm bracket of 157 HU inserted into a long bone (2.2 mm of 1,212 HU cortex round
    -67 HU marrow) that the field of view cuts along its length. Through the bracket's hole, wider than the 10 mm the
    plug closes, the marrow was one region with the outside: 6.9 cm^3 of cortex 3 mm thick, too thin for a bone, and
    the CT was refused with 19 cm^3 of bone in view. Holes up to 16 mm are plugged when the 10 mm plug gives no cortex
    (``bone_recognition.WIDE_PLUG_MM``). Measured: 6,944 IPC points, all on the bone, 81.9 % of it covered."""
    volume, truth = make_family_ct(51017, "full", overrides=wide_bracket_overrides(51017))
    _, score = run(volume, truth)
    assert not score.refused and score.ipc_on_body == 0 and score.ipc_on_bone == score.ipc_points > 6000
    assert score.coverage >= 0.75


def test_a_cut_off_a_solid_part_that_takes_most_of_the_bone_for_the_body_is_no_cut(caplog):
    """Fresh wide seed 51047: a 7.7 mm bar of 1,251 HU resting on a flat bone 8.6 mm thick (2 mm of 1,932 HU cortex),
    its frame below the threshold and its spheres unpaired, so only the bar's solid part says where the body is. The
    bone's core is within the bar's reach from an opening of 3.5 mm down, so the cut kept 3.8 of the object's 29.9
    cm^3, the stub's rule took the rest, and the CT was refused with "the bone has no surface at the threshold; check
    the threshold", a wrong lead. A cut off solid parts that leaves more bone on their side than it keeps is no cut;
    the bar is taken off whole instead (``without_solid_parts``), and the bone kept is the object less the bar (28.3
    cm^3 measured), not the 3.8 cm^3 piece."""
    volume, truth = make_family_ct(51047, "full", overrides=wide_bracket_overrides(51047))
    with caplog.at_level("INFO", logger="RAMSICPRegistrationLib.image.bone_recognition"):
        image = process_ct(volume, tool_markers=tool_marker_geometry(truth.tool_id))
    assert "reference body cut off the bone by an opening" not in caplog.text
    assert "the solid parts taken off the bone whole" in caplog.text
    bone = image.segmentation.recognition.verdict
    assert bone.verdict == "bone" and 25_000.0 < bone.volume_mm3 < 29_900.0


@pytest.mark.parametrize("seed, covered", [(12094, 0.95), (40317, 0.8), (40170, 0.7), (40173, 0.75)])
def test_the_bones_own_cortex_or_inside_is_not_followed_as_the_bodys_material(seed, covered):
    """Bones whose own cortex or inside is a plateau that a first form of the body's following took for the body's
    material. Family seed 12094 (full profile): a long bone's 1,334 HU cortex round marrow, thick enough to be a
    plateau (solid, part of its ring outside the bone), an 11.1 mm bracket of 429 HU inserted; the tibia was refused.
    Wide seed 40317: a long bone's 783 HU cortex round a 426 HU inside, a 20 mm bar of 295 HU resting on it; refused.
    Wide seed 40170: an ilium's 265 HU inside, bared where its 7.2 mm bracket of 957 HU was taken, taken next; 14 % of
    the bone covered, against 74 %. A plateau that is a shell round a cavity is the cortex (12094); the first plateau's
    level must be on the body's side of the cut too (40317); a later one's not the level of the bone's inside far from
    the body (40170). Wide seed 40173: a 9.5 mm bracket of 223 HU inserted into a flat bone whose cancellous inside
    is 257 HU, one plateau with it; taken, it held 92 % of the inside far from the body, and 27.3 % of the bone was
    covered, against 77.5 %: a plateau holding most of that inside is the bone's (a bracket kept with the bone, at most
    29 % of it in the wide CTs, its own part far from the body). Measured: 99.2 %, 86.1 %, 74.3 % and 77.5 % of the
    bone covered, none of the IPC on the body (40170's bracket left 322 points on it before the following)."""
    volume, truth = make_family_ct(seed, "full", overrides=wide_bracket_overrides(seed) if seed >= 40000 else None)
    image, score = run(volume, truth)
    assert not score.refused and score.ipc_on_body == 0 and score.coverage >= covered


def test_a_thin_bar_under_noise_is_followed_past_the_frame_it_joins():
    """Wide seed 40278: a 7.3 mm square bar of 1,479 HU resting on a flat bone 8.2 mm thick, its 196 HU frame joined
    to the bar's far end, 51 HU of noise. The opening cut the frame off the bar's end and the frame's plateau was
    followed, but on cells of 1.5 mm no 3 x 3 x 3 neighbourhood of the bar's is flat enough for its level, averaged or
    not: the bar stayed with the bone, 2,407 of 28,054 IPC points on it, exit 0. Its level is now read among its deep
    cells' own neighbours. Measured: 25,763 points, all on the bone; 97.4 % of the bone covered (97.0 % before)."""
    volume, truth = make_family_ct(40278, "full", overrides=wide_bracket_overrides(40278))
    image, score = run(volume, truth)
    assert not score.refused and score.ipc_on_body == 0 and score.ipc_on_bone == score.ipc_points
    assert score.coverage >= 0.95 and image.segmentation.body_followed.any()


def test_a_bar_inserted_into_a_bone_with_a_dim_cortex_is_followed_by_its_material():
    """Fresh wide seed 49030: an 8.6 mm square bar of 1,317 HU inserted into a flat bone 9.5 mm thick whose 723 HU
    cortex round a 484 HU inside reads only +96 HU on its rim, its ring frame of 376 HU cut off the bar's end. The
    frame's plateau the cut kept, and then the bar's, were refused because the bone left was no bone with a cortex
    (150 HU): 1,544 of 33,730 IPC points were the bar's, exit 0. The bone left must now be what a cut may keep
    (``_bone_cut_off``: a rim more than a solid part's brighter) with 0.9 of the rim of the bone it was taken from
    (``KEPT_RIM_SHARE``). Measured: 1 of 31,930 points on the body (29 mm from the bone, in the blur where the bar
    meets its frame), 96.6 % of the bone covered (as before)."""
    volume, truth = make_family_ct(49030, "full", overrides=wide_bracket_overrides(49030))
    image, score = run(volume, truth)
    assert not score.refused and score.ipc_on_body <= 2 and score.ipc_on_bone >= 0.9995 * score.ipc_points
    assert score.coverage >= 0.95 and image.segmentation.body_followed.any()


def test_no_level_is_read_among_the_kept_cells_own_neighbours_before_a_plateau_is_taken():
    """Wide seed 40185: a 13.3 mm bar of 2,221 HU resting on a flat bone 14.8 mm thick under a layer of tissue, its
    1,705 HU plate and bright spheres. With no level across the first cut, a level read among the kept cells' own
    neighbours (as the later steps may: a thin bar after its frame) was 505 HU, between the bone's 1,037 HU cortex and
    its 294 HU inside: 156 cm^3 of the bone was taken for the body's, the recognition fell back to the
    spheres alone, and its following left the bar's end on the bone (83 IPC points on it). Measured: 31,740 points, all
    on the bone, as before this round."""
    volume, truth = make_family_ct(40185, "full", overrides=wide_bracket_overrides(40185))
    _, score = run(volume, truth)
    assert not score.refused and score.ipc_on_body == 0 and score.ipc_on_bone == score.ipc_points > 30000


@pytest.mark.parametrize("seed, covered", [(49004, 0.92), (49044, 0.85)])
def test_a_bar_as_thick_as_the_bone_is_followed_from_its_solid_part_where_no_sphere_says_where_the_body_is(
    seed, covered
):
    """Fresh wide seeds 49004 (a 15 mm square bar of 1,359 HU from a plate of that HU, resting on a flat bone 16.7 mm
    thick, its spheres cut by the field of view and not paired) and 49044 (a 14.6 mm round bar of 2,433 HU from its
    plate, 1,267 HU posts, no sphere found, on a flat bone 16.7 mm thick). The solid part (the plate) tells the body,
    but no opening parts the bar from the bone, and the CT was refused with 87 and 57 cm^3 of bone in view. The body
    is now followed by its material from the solid part's seeds, where the body's side takes nothing like bone; the
    pieces the plateaus split off the bone (49044's posts, 65 IPC points 29-55 mm from the bone) go with them.
    Measured: 35,263 and 18,088 points, all on the bone; 94.2 % and 87.0 % of the bone covered."""
    volume, truth = make_family_ct(seed, "full", overrides=wide_bracket_overrides(seed))
    image, score = run(volume, truth)
    assert not score.refused and score.ipc_on_body == 0 and score.ipc_on_bone == score.ipc_points
    assert score.coverage >= covered and image.segmentation.body_followed.any()


def test_a_frame_whose_rest_hides_the_cortex_behind_a_metal_bracket_is_followed_with_it():
    """Fresh wide seed 53044: a star frame of 609 HU, its arms 9.3 mm thick (as thick as the bone), and its 2,303 HU
    square bracket 9 mm across inserted into a fibula in air; two spheres cut by the field of view, the other two
    unpaired. The frame's plateau was refused because the fibula it left, the bracket still in it, had no cortex, and
    nothing was followed: 12,840 of 19,071 IPC points lay on the frame and the bracket, exit 0. A plateau that leaves
    no cortex is now taken when the next one (the bracket's) leaves bone with one. Measured: 6,111 points, all on the
    bone, 90.4 % of it covered."""
    volume, truth = make_family_ct(53044, "full", overrides=wide_bracket_overrides(53044))
    image, score = run(volume, truth)
    assert not score.refused and score.ipc_on_body == 0 and score.ipc_on_bone == score.ipc_points
    assert score.coverage >= 0.88 and image.segmentation.body_followed.any()


def test_a_frame_arm_held_to_the_bone_by_a_followed_bar_s_blurred_rim_goes_with_the_body():
    """Fresh wide seed 53010: a 1,642 HU square bar 8.3 mm across resting on a fibula under 73 HU of noise, from a
    1,009 HU star frame 3.4 mm thick. The bar is followed by its material, but the blurred rim it left joined an arm
    of the frame (too thin for a level of its own) to the fibula: 122 of 1,036 IPC points lay on the arm, 30-60 mm off
    the bone, exit 0. The pieces the following split off are looked for again with the bone opened by 3 cells: 3 of
    935 are left on the arm (the bone's coverage, 28.3 %, as before: a steel pin's metal zone takes most of it)."""
    volume, truth = make_family_ct(53010, "full", overrides=wide_bracket_overrides(53010))
    _, score = run(volume, truth)
    assert not score.refused and score.ipc_on_body <= 5 and score.ipc_on_bone >= 0.99 * score.ipc_points
    assert score.coverage >= 0.27


def test_a_bone_s_far_side_a_followed_bracket_splits_off_stays_the_bone_s():
    """Wide seed 40260: a 463 HU round bracket 8.5 mm across inserted through a fibula 10 mm thick, followed by its
    material. With the bone opened by 3 cells to find the body's pieces the following split off (53010's arm), the
    fibula's far side past the bracket (1.2 cm^3, a +992 HU cortex) went with them in a first form: 95.0 -> 82.8 % of
    the bone covered. A piece with a cortex stays the bone's: 7,960 IPC points, all on the bone, 95.0 % covered."""
    volume, truth = make_family_ct(40260, "full", overrides=wide_bracket_overrides(40260))
    _, score = run(volume, truth)
    assert not score.refused and score.ipc_on_body == 0 and score.ipc_on_bone == score.ipc_points
    assert score.coverage >= 0.94


def test_a_bar_the_bone_kept_is_not_followed_into_a_rim_that_was_no_bones():
    """Wide seed 40131: a 13.6 mm bar of 612 HU resting on a long bone (941 HU cortex 3.7 mm thick round a 56 HU
    inside) of which 2.9 cm^3 is in view, its 1,001 HU ring frame and 335 HU spheres and posts, 37 HU of noise.
    Followed from the spheres, the frame is taken; what is left is mostly the bar, its rim dimmer than a cortex but
    brighter than a solid part's (+69 to +87 HU, with and without the posts' plateau and the pieces split off), which a
    cut may keep. Two first forms of this round's changes took it for the bone: 8,865 and 8,939 of about 11,100 IPC
    points were the bar's, exit 0. Such a rim is the bone's only where what it was taken from had it already, and it
    is refused, as before (no opening or plateau parts the bar from the little bone there is)."""
    volume, truth = make_family_ct(40131, "full", overrides=wide_bracket_overrides(40131))
    with pytest.raises(NoBoneSurface, match="no object in the CT's field of view is plausibly bone"):
        process_ct(volume, tool_markers=tool_marker_geometry(truth.tool_id))


def test_a_flat_bone_solid_through_far_from_the_spheres_is_not_refused_as_their_frame():
    """Family seed 18066 (full profile, from the batch 18000-18099): a flat bone whose cancellous inside (595
    HU) is nearly as bright as its 704 HU cortex (rim +48 HU), apart from the reference body (its bracket short of
    the bone), 64-92 mm from the 4 spheres found. It was refused as the body's solid frame with 46 cm^3 of bone in
    view; a frame holds its spheres within a post's reach, so it is the bone now."""
    volume, truth = make_family_ct(18066, "full")
    _, score = run(volume, truth)
    assert not score.refused and score.ipc_on_body == 0 and score.ipc_on_bone == score.ipc_points
    assert score.coverage >= 0.95 and score.found == score.visible == 3  # 97.7 % measured


def test_a_solid_frame_the_seeds_miss_is_not_grown_into_the_bone_through_its_bracket():
    """Family seed 18037 (full profile, fresh batch): an ilium 8 mm thick, a 4.8 mm metal bracket (2,213 HU) resting
    on it from a ring frame of 6 mm rods (2,480 HU), the spheres on 17 mm posts. The spheres' seeds and those of the
    frame's solid junctions did not reach the ring's far side: the bone's core grew into it through the bracket at an
    opening of 2 mm, and 12,640 of 69,922 IPC points lay on the ring, 39-63 mm off the bone, with exit 0. A solid part
    the core grows far from the bone is set apart as the body's now: the IPC is on the bone."""
    volume, truth = make_family_ct(18037, "full")
    _, score = run(volume, truth)
    assert not score.refused and score.found == score.visible == 4
    assert score.ipc_on_body == 0 and score.ipc_on_bone == score.ipc_points
    assert score.coverage >= 0.9  # 93.6 % measured, as before (when the ring's points were in the IPC too)


@pytest.mark.parametrize("seed, overrides", [(11094, None), (32007, {"frame": "plate", "bracket": "inserted"})])
def test_a_body_that_no_sphere_tells_is_told_by_the_solid_part_its_bracket_leads_to(seed, overrides):
    """No sphere says where the body is, and no opening splits its frame off the bone, thinner than the bracket
    that joins them. 11094 (full profile): a 9.3 mm metal bracket (1,637 HU) inserted into a tibia from a dim ring
    frame (353 HU), three spheres cut by the field of view: 3,158 IPC points on the bracket and frame. 32007 (first
    met as a held-out draw; the plate and the inserted bracket forced): plastic spheres sunk into a 5 mm plate of
    1,034 HU, on a 6.9 mm bracket inserted into a flat bone: 40,764 of 70,257 IPC points on the plate. The bone's
    core, grown from its thickest part, reaches the frame beyond the bracket, which is solid: that is the body's
    now."""
    volume, truth = make_family_ct(seed, "full", overrides=overrides)
    _, score = run(volume, truth)
    assert not score.refused and score.visible == 0
    assert score.ipc_on_body == 0 and score.ipc_on_bone == score.ipc_points
    assert score.coverage >= 0.9  # 97.0 and 94.2 % measured (96.9 and 94.1 % before, with the body's points)


def test_a_short_rod_no_sphere_tells_is_set_apart_as_the_solid_part_the_bones_core_grows():
    """Family seed 35090: an 8.3 mm rod of 614 HU inserted into a flat bone (its inside 520 HU), standing 27 mm out
    of it into air to a 113 HU plate whose plastic spheres (154 HU) are sunk in it: no sphere is found, and only the
    rod is above the threshold. The bone's core grew the rod at an opening of 2.75 mm, beyond 7.5 mm from the bone a
    solid piece (rim -9 HU on its inside) of 57 mm^3, under the 100 mm^3 a core had to have: the rod was kept with the
    bone, 806 of 23,083 IPC points on it, exit 0. Where no seed holds the body, a solid piece the core grows counts
    from 40 mm^3 now (``bone_recognition.MIN_GROWN_SOLID_MM3``). Measured: 22,366 of 22,366 on the bone, 98.0 % of it
    covered (97.5 % before)."""
    volume, truth = make_family_ct(35090, "full")
    _, score = run(volume, truth)
    assert not score.refused and score.visible == 0
    assert score.ipc_on_body == 0 and score.ipc_on_bone == score.ipc_points
    assert score.coverage >= 0.95


@pytest.mark.parametrize("seed", [13028, 15030])
def test_a_body_the_threshold_breaks_into_pieces_still_leads_to_its_bracket(seed):
    """The reference body about the threshold (200 HU) falls into pieces smaller than any bone, and the spheres' dim
    parts stopped at them. 13028 (full profile): a ring frame of 215 HU in pieces of 0.3-0.7 cm^3, its 9.4 mm metal
    bracket (2,252 HU) resting on a tibia from the ring's hub, three spheres cut: 7,125 of 20,290 IPC points on the
    bracket. 15030: a dim ring (105 HU) on a 4.7 mm bracket of 222 HU inserted into a tibia: 103 points on it. The
    pieces lead on as dim parts now: the bracket is reached, and cut off the bone."""
    volume, truth = make_family_ct(seed, "full")
    _, score = run(volume, truth)
    assert not score.refused and score.ipc_points > 5000
    assert score.ipc_on_body == 0 and score.ipc_on_bone == score.ipc_points
    assert score.coverage >= 0.8  # 83.8 and 88.6 % measured (95.0 and 88.6 % before, with the bracket's points)


@pytest.mark.parametrize(
    "seed, overrides, on_bone",
    [(33028, {"frame": "star", "bracket": "resting"}, 1.0), (14163, None, 1.0), (23065, None, 0.99)],
)
def test_the_holes_noise_leaves_in_a_dim_bracket_are_no_marrow(seed, overrides, on_bone):
    """Noise leaves holes below the 200 HU threshold in a bracket about it, which the cut took for the marrow of a
    thin shaft of bone: the bracket was kept with the bone. 33028 (first met as a held-out draw; the star frame and
    the resting bracket forced): a 10 mm bracket of 229 HU under 61 HU of noise on a tibia in air, 3,402 of 32,363
    IPC points inside it. 14163 (full profile): an 11.5 mm bracket of 214 HU under 35 HU inserted into a tibia, 158
    points. The holes are 48 and 34 HU darker than the bracket round them, where a marrow cavity is darker than its
    cortex by a cortex's contrast (150 HU): they are no marrow now, and the bracket is cut off. 23065 (full profile):
    an 8 mm bracket of 333 HU under 71 HU of noise resting on a long bone, three holes 161 HU darker, a cell each
    and no two sharing a face, 117 of 10,189 IPC points on it; a marrow cavity's cells are neighbours."""
    volume, truth = make_family_ct(seed, "full", overrides=overrides)
    _, score = run(volume, truth)
    assert not score.refused and score.found == score.visible >= 3
    assert score.ipc_on_body == 0 and score.ipc_on_bone >= on_bone * score.ipc_points  # 23065: 99.1 % measured
    assert score.coverage >= 0.9  # 94.5, 96.5 and 99.1 % measured (95.2, 97.7 and 99.1 % with the bracket's points)


def test_a_cavity_beside_a_bracket_is_no_marrow_of_it():
    """Family seed 23012 (first met in a fresh batch): a 6.4 mm bracket of 2,089 HU resting on a tibia, its plate as
    bright. Where the bracket leaves the bone, the cut took two cells of soft tissue 1.5 mm outside it (3.6-4.0 mm
    from its core) for the marrow of a shaft of bone: the bracket's whole length from the bone to its plate was kept
    with the bone, and 398 of 9,003 IPC points lay on it, up to 16 mm off the bone, with exit 0. A shaft's marrow is
    where its core runs: over 600 family CTs, each of the 20 pieces of bone that met this check had 2-203 of its
    cavity's cells within 1 mm of its core, and the cavities beside 6 of the 7 pieces of brackets lay 2.4-5.5 mm from
    them (the seventh's are noise holes in its core, 23065). The bracket is cut off now."""
    volume, truth = make_family_ct(23012, "full")
    _, score = run(volume, truth)
    assert not score.refused and score.found == score.visible == 4
    assert score.ipc_on_body == 0 and score.ipc_on_bone >= 0.98 * score.ipc_points


@pytest.mark.parametrize("seed, on_body", [(13011, 2), (19085, 2), (14026, 2), (14007, 3)])
def test_the_mouth_of_a_dim_brackets_hole_is_left_out_with_its_walls(seed, on_body):
    """Family seeds 13011 and 19085: a 10.7 and a 9.5 mm bracket of 156 and 138 HU inserted into a long bone. The
    envelope plugs the hole the bracket makes in the cortex only up to 1-2.5 mm under the bone's surface (its
    closing cannot reach further into a hole narrower than it): the wall above the plug, 95 and 102 IPC points on the
    bracket 0.5-2.4 mm inside the bone, stayed in the IPC. All of them lie within 2.3 mm of the inner wall left out,
    along the surface: the mouth (``MOUTH_MM``) goes with it now: 0 and 1 points on the body measured. In 14026 most
    of the hole's wall has no cortex under it either: the mouth is found with the wall's points (without them, the
    wall left was too small to have a mouth: 21 points on the bracket; 1 now). In 14007, a 105 HU bracket inserted
    into a flat bone, the dim part beside the wall is left out before (with it, the mouth was too large to be a
    hole's: 23 points on the bracket; 3 now, 0.3 mm off it, as before)."""
    volume, truth = make_family_ct(seed, "full")
    _, score = run(volume, truth)
    assert not score.refused
    assert score.ipc_on_body <= on_body and score.ipc_on_bone >= 0.99 * score.ipc_points


def test_dim_parts_led_on_into_the_bone_do_not_leave_it_without_a_cortex():
    """Family seed 24095 (first met in a fresh batch): a reference body below the threshold (spheres 162 HU, frame
    and a 10.7 mm bracket 145 HU) resting on a tibia under 70 HU of correlated noise. The dim parts led the spheres
    on to the bone's object (the bracket's specks above the threshold touch it), which was then the body's: no object
    had a cortex, a 1.7 cm^3 piece of the frame was taken for the bone, and the CT was refused though 25.8 cm^3 of
    bone lay in view. With the spheres and their posts' feet alone the tibia has its cortex (+352 HU): taken then."""
    volume, truth = make_family_ct(24095, "full")
    _, score = run(volume, truth)
    assert not score.refused and score.found == score.visible == 3
    assert score.ipc_on_body == 0 and score.ipc_on_bone >= 0.99 * score.ipc_points
    assert score.coverage >= 0.9  # 95.1 % measured


def test_a_frame_brighter_than_the_cortex_where_a_dimmer_bracket_meets_it_is_no_piece_of_bone():
    """Family seed 25023 (full profile, first met in a fresh batch): plastic spheres (138 HU) on dim posts lead to a
    2,032 HU plate, whose 812 HU bracket rests on a tibia of 1,118 HU; bone and body are one object. The dim parts
    alone lead to it, so the body's side of the cut must hold no piece of bone; the plate's rim round the junction
    with the bracket (1,374 HU inside) read as a cortex (+623 HU), and the tibia (42 cm^3 in view) was refused. A
    piece of the bone holds its marrow, darker than the bone's own rim: the tibia is cut off the body now."""
    volume, truth = make_family_ct(25023, "full")
    _, score = run(volume, truth)
    assert not score.refused and score.found == score.visible == 4
    assert score.ipc_on_body == 0 and score.ipc_on_bone == score.ipc_points
    assert score.coverage >= 0.9  # 94.0 % measured


@pytest.mark.parametrize("seed, on_body", [(25043, 3), (22051, 0)])
def test_a_dim_bracket_far_above_a_low_surface_level_adds_no_surface_without_a_cortex(seed, on_body):
    """Family seeds 25043 and 22051: dim brackets of 194 and 174 HU, resting on a long bone and inserted into a flat
    one, in air; the surface level read across the bone is -34 and -16 HU. The bracket lies some 200 HU above the
    level, too far for a part "about as bright as the level" (``NO_CORTEX_SHARE``): 180 and 121 IPC points lay on
    it, up to 10 mm off the bone. The CT 0.5-1 mm under most of them rises above the level by less than 0.3 of the
    cortex's rise (``DIM_PEAK_SHARE``; 25043: a median of 0.23): 12 and 0 points were left on the bracket. Of
    25043's last 12, 0.5-7.2 mm off the bone at 0.30-0.43, the 9 where the bracket lies beyond go with the corner
    (``CORNER_PEAK_SHARE``): 3 are left."""
    volume, truth = make_family_ct(seed, "full")
    _, score = run(volume, truth)
    assert not score.refused
    assert score.ipc_on_body <= on_body and score.ipc_on_bone >= 0.99 * score.ipc_points


@pytest.mark.parametrize("seed, before, after", [(25047, 29, 14), (23093, 33, 20)])
def test_the_corner_a_dim_bracket_makes_with_the_bone_is_left_out(seed, before, after):
    """Family seeds 25047 and 23093: brackets of 109 and 154 HU resting on a flat bone and a fibula in air. Where
    the rounded end meets the bone, the blur fills the corner above the surface level: 29 and 33 IPC points 0.5-2.2
    mm off the bone. The CT 0.5-1 mm under them rises above the level by 0.3-0.45 of the cortex's rise, and beyond
    them lies the bracket, brighter than the air the rest of the surface touches (``CORNER_PEAK_SHARE``,
    ``CORNER_BRIGHTER_HU``): 14 and 20 are left, and the bone keeps its surface."""
    volume, truth = make_family_ct(seed, "full")
    _, score = run(volume, truth)
    assert not score.refused and score.found == score.visible
    assert score.ipc_on_body <= after < before
    assert score.ipc_on_bone >= 0.99 * score.ipc_points and score.coverage >= 0.95  # 97.9 and 96.3 % measured


@pytest.mark.parametrize("seed, before", [(19050, 5), (24058, 4), (26070, 3)])
def test_where_a_part_dimmer_than_the_bone_meets_it_its_corner_is_left_out(seed, before):
    """Family seeds 19050, 24058, 26070: brackets of 117, 125 and 101 HU resting on a flat bone in tissue, on a
    long bone in air and inserted into one in tissue. Their corner with the bone, with a cortex under it, lifted the
    surface 0.5-1.4 mm off the bone into the bracket: 5, 4 and 3 IPC points. ``dim_parts`` finds where each meets
    the bone's blur, and the points near there that touch something brighter than the rest of the surface touches
    go with the corner: none is left, and the coverage of the bone is as before (98.5, 97.3, 96.6 %)."""
    volume, truth = make_family_ct(seed, "full")
    _, score = run(volume, truth)
    assert not score.refused and score.found == score.visible
    assert score.ipc_on_body == 0 < before
    assert score.ipc_on_bone == score.ipc_points and score.coverage >= 0.96


def test_a_cap_seen_through_the_hole_of_a_plate_does_not_pull_its_sphere_off_centre():
    """Family seed 19038 (full profile, first met in a fresh batch): four spheres of 1,775 HU sunk into a 618 HU plate
    (the generator calls them hidden). Each is seen below the plate and through its hole, a cap whose edge the plate's
    blur pushes 0.21-0.24 mm out; the fit takes both, pulled 0.17-0.18 mm along the hole's axis, as clean as any
    (RMS 0.056 mm): sphere 3, seen over 78 %, was usable, 0.168 mm off. The cap apart from the rest flags it now."""
    volume, truth = make_family_ct(19038, "full")
    image, score = run(volume, truth)
    assert score.false == 0 and not image.usable
    third = [sphere for sphere in image.spheres if sphere.number == 3]
    assert third and third[0].status == "partial" and "seen apart from the rest" in third[0].note
    assert score.ipc_on_bone == score.ipc_points > 5000


def test_sunk_spheres_seen_over_85_to_95_percent_are_centred_clear_of_what_hides_them():
    """Wide seed 41003 (first met under the benchmark's --noise-hu; the same at its own 2.9 HU): spheres of 2,930 HU
    sunk into a 158 HU star frame 11.1 mm thick, under 80 % of each bare (the generator calls them hidden). The
    frame's blur fills in their edge beside it, so two are seen over 88-89 %, past the 85 % below which a sphere is
    centred without the edges next to its hidden piece; the whole edge, clean (RMS 0.06 mm), put them 0.16-0.17 mm
    off, usable: two false spheres. Centred clear of that border as a clean fit seen under 95 %: 0.07 mm."""
    volume, truth = make_family_ct(41003, "full", overrides=wide_bracket_overrides(41003))
    image, score = run(volume, truth)
    assert score.false == 0 and len(image.usable) == 3
    for sphere in image.usable:
        assert np.linalg.norm(sphere.centre - truth.marker_centres[sphere.number - 1]) < 0.1


def test_spheres_as_bright_as_their_thick_posts_are_usable_when_their_fit_is_round():
    """Family seed 23015 (full profile, a fresh batch): three visible spheres of 238 HU on 5.7 mm posts of 243 HU,
    with a ramp of partial volume. The posts hide 16-18 % of each sphere, and the edge fits it at 0.08-0.10 mm RMS:
    they were flagged partial (seen under 85 %, a sphere needed an RMS within 0.06 mm), and the CT gave no usable
    sphere, though each centre was 0.06-0.07 mm off. Their fitted radius is the nominal's within 0.07 mm: usable now."""
    volume, truth = make_family_ct(23015, "full")
    image, score = run(volume, truth)
    assert score.visible == 3 and score.found == 3 and score.false == 0
    for sphere in image.usable:
        assert sphere.coverage < 0.85 and sphere.residual_mm > 0.06  # taken by the round fit, not the old rule
        assert np.linalg.norm(sphere.centre - truth.marker_centres[sphere.number - 1]) < 0.1


def test_a_flat_bone_the_round_field_of_view_cuts_open_is_not_refused_as_too_thin():
    """Family seed 28060 (full profile, a fresh batch): a flat bone (two 1.4 mm tables of 991 HU round a 168 HU
    inside, below the threshold) that the round field of view cuts. Its inside reaches the padding, so it was not
    filled: 18.5 cm^3 of tables less than 4 mm thick, "too small or thin", and the CT was refused with 56 cm^3 of
    bone in view. Walled by the padding (the CT's side), its inside is filled and its cortex shows."""
    volume, truth = make_family_ct(28060, "full")
    _, score = run(volume, truth)
    assert not score.refused and score.ipc_points > 10000
    assert score.ipc_on_bone == score.ipc_points and score.coverage >= 0.7  # 18,118 points, 73.2 % measured


def test_two_spots_of_the_body_at_a_tool_distance_by_chance_do_not_hold_the_bone_to_it():
    """Family seed 19089 (full profile, first met in a fresh batch): no marker sphere is in view clean (three cut,
    one of 210 HU sunk into a 1,146 HU star frame), but a 10.8 mm bracket's end, 7.5 mm from a tibia it is inserted
    into, and a frame arm fit spheres 62.8 mm apart, one of the tool's distances (64.3 mm): tied as the body's, the
    first held the bone's core to the body, and the CT was refused. With no bone found, the recognition looks once
    more without them: the bracket is cut off."""
    volume, truth = make_family_ct(19089, "full")
    image, score = run(volume, truth)
    assert not score.refused and image.segmentation.body is not None
    assert score.ipc_points > 20000 and score.ipc_on_bone >= 0.99 * score.ipc_points
    assert score.coverage >= 0.9  # 96.8 % measured; 71 of 30,531 points inside the body, at the bracket's stub
    assert score.false == 0 and not image.usable


def test_a_bracket_end_in_the_marrow_tied_to_two_true_spheres_does_not_make_the_bone_the_body():
    """Family seed 27033 (full profile, a fresh batch): a tibia in air with a 10.8 mm, 1,040 HU bracket inserted into
    its marrow; of the reference body one sphere is in view clean, one damaged, two cut. The bracket's round end in
    the marrow fits a sphere (radius 5.35 mm, seen over half) at one of the tool's distances from the two true ones:
    tied with them as the body's, it held the tibia to the body, and the cut kept 1.5 cm^3 of the frame as the bone.
    The IPC written was 223 points, every one on the reference body, with exit 0. With spheres only tied, a cut that
    leaves on the body's side a piece with a cortex round its inside, larger than the bone it keeps, is no cut: the
    recognition looks once more without them, and the IPC is the tibia's."""
    volume, truth = make_family_ct(27033, "full")
    image, score = run(volume, truth)
    assert image is not None and image.pairing is None  # the spheres were tied, not paired
    assert score.ipc_on_body == 0 and score.ipc_points > 20000
    assert score.ipc_on_bone == score.ipc_points and score.coverage >= 0.85  # 34,495 points, 91.2 % measured
    assert score.false == 0 and not image.usable


def test_a_spot_of_the_bone_tied_to_a_true_sphere_costs_the_bone_only_that_spot():
    """Family seed 25005 (full profile): spheres sunk into an 11 mm ring frame, one cut; a spot of a flat bone at the
    field of view's edge fits a sphere (5.07 mm, partial) at one of the tool's distances from a true one, and both
    are tied as the body's. The cut round that spot keeps the rest of the bone. Forbidding any bone-like piece on
    the body's side (as for 27033) threw that cut away, and the bone, taken whole, held the spot's "sphere": refused.
    With tied spheres, only a bone-like piece larger than the bone kept undoes the cut."""
    volume, truth = make_family_ct(25005, "full")
    image, score = run(volume, truth)
    assert image is not None and image.pairing is None and image.segmentation.body is not None
    assert score.ipc_on_body == 0 and score.ipc_on_bone == score.ipc_points > 20000  # 34,442 measured
    assert score.coverage >= 0.45  # 50.6 % measured: the bone is cut by the field of view


def test_two_round_ends_of_bone_do_not_number_a_true_sphere_as_the_wrong_marker():
    """Family seed 27015 (full profile, a fresh batch): a flat bone in air with two of the reference body's spheres
    in view, clean, and two cut off. Two round ends of the bone's rim fit spheres badly (radius 5.3 mm, 0.3 mm RMS:
    deformed) and lie, with one true sphere, at the tool's distances (FRE 0.28 mm): that pairing numbered the true
    sphere as marker 4 (it is marker 2), the two ends as markers 2 and 3, and took the bone for the body (refused).
    A pairing must now hold at least two round spheres: the two true spheres are tied instead, unnumbered, and the
    IPC is the bone's."""
    volume, truth = make_family_ct(27015, "full")
    image, score = run(volume, truth)
    assert image is not None and image.pairing is None and not image.usable
    assert score.false == 0 and score.cut_usable == 0
    clean = [sphere for sphere in image.spheres if sphere.status == "ok"]
    assert len(clean) == 2 and all(sphere.number == 0 for sphere in clean)
    assert all(np.linalg.norm(truth.marker_centres - sphere.centre, axis=1).min() < 0.05 for sphere in clean)
    assert score.ipc_on_body == 0 and score.ipc_points > 10000
    assert score.ipc_on_bone == score.ipc_points and score.coverage >= 0.8  # 15,392 points, 83.1 % measured


def test_a_bone_the_round_field_of_view_cuts_along_its_length_is_not_refused_as_a_solid_frame():
    """Family seed 12013 (full profile): a tibia (cortex 725 HU, 3 mm; marrow -54 HU) that the round field of view
    cuts along its length, a steel pin through it, 3 spheres in view. The cells the field of view's edge runs through
    (part padding, part CT) joined its marrow to the tissue round it, so the marrow was not filled as its inside: its
    deepest cells were the cortex and the pin (+2,487 HU), its rim read -1,850 HU on them, and the tibia was refused
    as the body's solid frame. Those cells are the CT's side now: the marrow is its inside (rim +681 HU), and the IPC
    is the bone's."""
    volume, truth = make_family_ct(12013, "full")
    _, score = run(volume, truth)
    assert not score.refused and score.ipc_points > 1000
    assert score.ipc_on_bone == score.ipc_points and score.coverage >= 0.70  # 1,659 points, 72 % covered measured


@pytest.mark.parametrize("seed, covered", [(40010, 0.88), (40013, 0.92), (40029, 0.85)])
def test_a_bracket_wider_than_14_mm_is_cut_off_a_bone_thicker_still(seed, covered):
    """Wide brackets (``wide_bracket_overrides``, full profile): 40010 a 14.9 mm square bar resting on a 23 mm long
    bone, 40013 a 16.7 mm square bar inserted into a 27 mm one, 40029 a 17.8 mm square bar resting on a 26 mm one
    (its frame dim, 151 HU). With 7 mm the largest opening, each bar was kept with the bone, whole: 6,359, 2,036 and
    7,407 IPC points on it. The 9 and 11 mm openings cut it off; a margin of the rod's opening round its foot (10 mm)
    left out a ring of the bone as wide (86, 88 and 80 % covered), 3.5 mm leaves 91, 95 and 88 %."""
    volume, truth = make_family_ct(seed, "full", overrides=wide_bracket_overrides(seed))
    _, score = run(volume, truth)
    assert not score.refused and score.ipc_on_body == 0 and score.ipc_on_bone >= 0.99 * score.ipc_points
    assert score.coverage >= covered


def test_a_sphere_swollen_by_the_frame_it_is_sunk_into_is_not_usable():
    """Wide seed 40088: four 517 HU spheres sunk into a 104 HU star frame 11.5 mm thick. The frame's blur pushes the
    edges out where it holds them: one sphere, seen over 86 % with a fitted radius 0.10 mm over the nominal, was
    clean and 0.27 mm off. A sphere partly hidden and larger than the nominal is partial now: none is usable."""
    volume, truth = make_family_ct(40088, "full", overrides=wide_bracket_overrides(40088))
    image, score = run(volume, truth)
    assert score.false == 0 and not image.usable
    swollen = [sphere for sphere in image.spheres if "pushes its edge out" in sphere.note]
    assert swollen and all(sphere.status == "partial" and sphere.radius_mm > 5.8 for sphere in swollen)
    assert all(np.linalg.norm(truth.marker_centres - sphere.centre, axis=1).min() < 0.5 for sphere in image.spheres)


def test_a_ct_without_a_bone_is_refused_with_what_was_found(tmp_path, capsys):
    """The reference-body phantom with its shaft and soft tissue blanked out: only the body and its spheres."""
    volume, truth = make_reference_body_phantom(ReferenceBodyModel("aluminium", "aluminium"))
    grid = np.argwhere(np.ones(volume.voxels.shape, dtype=bool))
    ras = volume.ijk_to_ras_points(grid)
    voxels = volume.voxels.copy()
    shaft = np.hypot(ras[:, 0], ras[:, 1]) < SHAFT_RADIUS_MM + SOFT_TISSUE_MM + 2.0
    voxels[tuple(grid[shaft].T)] = -1000
    with pytest.raises(NoBoneSurface, match="no object in the CT's field of view is plausibly bone") as refusal:
        process_ct(CTVolume(voxels, volume.ijk_to_ras), tool_markers=tool_marker_geometry())
    assert "reference body" in str(refusal.value) and "holds" in str(refusal.value)
    # The marker spheres were found all the same: the coarse registration can use them.
    usable = refusal.value.usable
    assert sorted(sphere.number for sphere in usable) == [1, 2, 3, 4]
    errors = [np.linalg.norm(sphere.centre - truth.marker_centres[sphere.number - 1]) for sphere in usable]
    assert max(errors) < 0.05
    # The command line says it in one line and exits 2, writing no IPC; the marker centres, when asked for.
    save_nrrd(tmp_path / "ct.nrrd", CTVolume(voxels, volume.ijk_to_ras))
    assert main(["ipc", str(tmp_path / "ct.nrrd"), "--out", str(tmp_path / "ipc.vtp")]) == 2
    error = capsys.readouterr().err.strip()
    assert "no object in the CT's field of view is plausibly bone" in error and "\n" not in error
    assert not (tmp_path / "ipc.vtp").exists()
    markers = tmp_path / "markers.mrk.json"
    assert main(["ipc", str(tmp_path / "ct.nrrd"), "--out", str(tmp_path / "ipc.vtp"), "--markers", str(markers)]) == 2
    error = capsys.readouterr().err.strip()
    assert "plausibly bone" in error and f"(4 of 4 usable) are in {markers}" in error and "\n" not in error
    written = read_markers(markers)
    assert sorted(written.numbers) == [1, 2, 3, 4] and set(written.statuses) == {"ok"}
    order = np.array(written.numbers) - 1
    np.testing.assert_allclose(written.points, truth.marker_centres[order], atol=0.05)
    assert not (tmp_path / "ipc.vtp").exists()


def test_a_refusal_is_right_only_when_the_bone_in_view_is_too_small_to_be_bone():
    """The benchmark judges a refusal by the bone inside the field of view: a capsule of radius 5 mm and 20 mm of
    cylinder holds pi 25 (20 + 20/3) mm^3 = 2,094 mm^3 (over the 1,500 of the smallest bone: a wrong refusal); with
    the reconstruction cylinder's edge through its axis, half of it (a right one)."""
    spacing = 0.5
    ijk_to_ras = np.diag([spacing, spacing, spacing, 1.0])
    shape = (80, 80, 80)  # 0-39.5 mm each way
    volume = CTVolume(np.full(shape, -1000, dtype=np.int16), ijk_to_ras)
    bone = Capsule(np.array([20.3, 19.6, 10.2]), np.array([20.3, 19.6, 30.2]), 5.0)  # off the 1 mm grid

    def truth(field_of_view):
        return FamilyTruth("8700339", None, None, 5.75, (), bone, None, None, field_of_view, {})

    whole = truth(FieldOfView(ijk_to_ras, shape))
    expected = np.pi * 25.0 * (20.0 + 20.0 / 3.0)
    assert whole.bone_in_view_mm3(volume) == pytest.approx(expected, rel=0.03)
    half = truth(FieldOfView(ijk_to_ras, shape, cylinder_centre_ij=(40.6 + 60.0, 39.2), cylinder_radius_mm=30.0))
    assert half.bone_in_view_mm3(volume) == pytest.approx(expected / 2.0, rel=0.05)
    refused = "no object in the CT's field of view is plausibly bone"
    assert not score_image_side(volume, whole, None, refused).rightly_refused
    assert score_image_side(volume, half, None, refused).rightly_refused
    assert not score_image_side(volume, half, None, "").rightly_refused


def test_overrides_force_one_choice_and_leave_the_others():
    _, drawn = make_family_ct(11, render=False)
    _, forced = make_family_ct(11, overrides={"sphere_hu": 2500.0}, render=False)
    assert forced.settings["sphere_hu"] == 2500.0
    assert {k: v for k, v in forced.settings.items() if k != "sphere_hu"} == {
        k: v for k, v in drawn.settings.items() if k != "sphere_hu"
    }
    with pytest.raises(ValueError, match="overrides sphere_colour: no such choice"):
        make_family_ct(11, overrides={"sphere_colour": "red"}, render=False)


def test_wide_bracket_overrides_leave_the_seeds_other_choices_and_its_square_bar_has_corners():
    """``wide_bracket_overrides`` forces the bracket's shape, width, state and cap only (every other choice as the
    seed draws it; the same overrides each time); a square bar of half-side r holds the point (0.9 r, 0.9 r) across
    its axis at mid-length, 1.27 r from the axis, which the round rod of radius r does not."""
    seed = next(seed for seed in range(100) if wide_bracket_overrides(seed)["bracket_shape"] == "square")
    overrides = wide_bracket_overrides(seed)
    assert overrides == wide_bracket_overrides(seed)
    _, drawn = make_family_ct(seed, render=False)
    _, forced = make_family_ct(seed, overrides=overrides, render=False)
    changed = set(overrides) | {"bracket_diameter_mm", "bracket_shape", "bracket_cap"}
    assert {k: v for k, v in forced.settings.items() if k not in changed} == {
        k: v for k, v in drawn.settings.items() if k not in changed
    }
    assert drawn.settings["bracket_shape"] == "round" and drawn.settings["bracket_cap"] == BRACKET_CAP
    bar = forced.bracket
    radius = forced.settings["bracket_diameter_mm"] / 2.0
    assert radius <= WIDE_BRACKET_CAP * forced.settings["bone_half_thickness_mm"] + 1e-9
    across, other, axis = bar.axes.T
    middle = np.asarray(bar.centre)
    assert bar.signed_distance(middle[None])[0] == pytest.approx(-radius, abs=1e-9)
    corner = middle + 0.9 * radius * (across + other)
    assert bar.signed_distance(corner[None])[0] < 0.0
    rod = Capsule(middle - bar.half_size[2] * axis, middle + bar.half_size[2] * axis, radius)
    assert rod.signed_distance(corner[None])[0] == pytest.approx((0.9 * np.sqrt(2.0) - 1.0) * radius, abs=1e-9)


def test_the_truth_has_known_answers():
    volume, truth = make_family_ct(2, overrides={"bone": "long", "cut_markers": [1], "cylinder": False}, render=False)
    # A point 2 mm off the long bone's surface along its radius is 2 mm from it.
    capsule = truth.bone
    axis = (capsule.end - capsule.start) / np.linalg.norm(capsule.end - capsule.start)
    side = np.cross(axis, [1.0, 0.0, 0.0])
    side /= np.linalg.norm(side)
    point = 0.5 * (capsule.start + capsule.end) + (capsule.radius + 2.0) * side
    assert truth.bone_distance(point[None])[0] == pytest.approx(2.0, abs=1e-9)
    # The field of view's corner voxel centre is on its edge; marker 1 was cut by a face of it.
    assert truth.field_of_view.clearance(volume.ijk_to_ras_points(np.zeros((1, 3))))[0] == pytest.approx(0.0)
    assert truth.marker_states[0] == "cut"
    assert truth.field_of_view.clearance(truth.marker_centres[:1])[0] < truth.marker_radius_mm


def test_the_family_spans_what_a_user_meets():
    """The draws of the first 300 seeds (not rendered) cover issue 27's ranges."""
    settings = [make_family_ct(seed, render=False)[1].settings for seed in range(300)]

    def values(name):
        return np.array([s[name] for s in settings])

    sphere, post, frame = values("sphere_hu"), values("post_hu"), values("frame_hu")
    assert sphere.min() < 130 and sphere.max() > 2500  # plastic to metal
    assert (frame > sphere + 100).mean() > 0.2 and (frame < sphere - 100).mean() > 0.2  # brighter and dimmer
    assert (post > sphere + 100).mean() > 0.2 and (post < sphere - 100).mean() > 0.2
    assert set(values("bracket")) == {"inserted", "resting", "short", "none"}
    assert set(values("frame")) == {"star", "ring", "plate"} and set(values("bone")) == {"long", "flat", "mesh"}
    assert set(values("partial_volume")) == {"ramp", "supersample", "sharp"}
    drawn = np.concatenate((values("in_plane_mm"), values("slice_mm")))
    assert drawn.min() < 0.32 and drawn.max() > 0.98 and drawn.max() <= 1.0
    fine = [make_family_ct(seed, "full", render=False)[1].settings["spacing_mm"] for seed in range(40)]
    assert min(min(spacing) for spacing in fine) < 0.5  # the benchmark's CTs keep fine voxels
    assert values("noise_hu").min() < 3 and values("noise_hu").max() > 60
    assert values("turned").mean() > 0.3 and values("cylinder").mean() > 0.1
    assert sum(len(s["cut_markers"]) for s in settings) > 60
    assert (values("bone_reach_mm") < 20).mean() > 0.1  # a short piece of bone in view


def test_a_metal_sphere_with_a_shallow_cap_cut_off_is_flagged_not_used():
    # Family seed 17022 (full profile): sphere 1 (2,943 HU, on a 6.2 mm post of 2,049 HU) has a cap cut off on its
    # free side, too shallow for its rays to find air within the radius; fitted, it was 0.20 mm off the truth, seen
    # over 77 % at 0.058 mm RMS, and marked usable. Its flat face's edges, inside the sphere, flag it now.
    volume, truth = make_family_ct(17022, "full")
    assert truth.marker_states[0] == "damaged"
    image = process_ct(volume, tool_markers=tool_marker_geometry(truth.tool_id))
    assert sorted(sphere.number for sphere in image.usable) == [2, 3, 4]
    flagged = [sphere for sphere in image.spheres if sphere.number == 1]
    assert flagged and flagged[0].status == "partial" and "inside it (a cap missing?)" in flagged[0].note
    errors = [np.linalg.norm(s.centre - truth.marker_centres[s.number - 1]) for s in image.usable]
    assert max(errors) < 0.05


def test_a_bracket_through_the_bone_is_followed_to_its_tip_out_of_the_far_side():
    """Family seed 16094 (full profile): a 6.2 mm bracket of 1,515 HU inserted into a tibia goes through it and out
    of its far side, 20-25 mm past the body's end, beyond the 20 mm its line was followed: 148 IPC points lay on its
    tip, with exit 0. Its axis stays at the bracket's HU through the bone and out, and the line is followed to its
    tip now: none."""
    volume, truth = make_family_ct(16094, "full")
    _, score = run(volume, truth)
    assert not score.refused and score.ipc_on_body == 0 and score.ipc_on_bone == score.ipc_points
    assert score.coverage >= 0.80  # 82.5 % measured, as before


def test_an_ipc_left_only_on_a_bar_the_bone_is_joined_to_is_refused():
    """Fresh wide seed 61018 at 62 HU of noise: a 16.4 mm square bar of 1,000 HU inserted into a long bone's end
    (9.3 cm^3 of it in view, a steel pin in it), two spheres cut by the field of view and two that cannot be numbered,
    so no seed holds the body and no cut parts it: one object, with a cortex (rim +670 HU on its inside). The pin's
    metal zone, the inner walls and the field of view's edge leave out the bone's own surface; what was left was the
    bar's: 11,467 of 11,469 IPC points on it, with exit 0. The cortex read under the IPC itself is the bar's (none):
    the CT is refused, and says why."""
    overrides = {**wide_bracket_overrides(61018), "noise_hu": 62.0}
    volume, truth = make_family_ct(61018, "full", overrides=overrides)
    image, score = run(volume, truth)
    assert image is None and score.ipc_on_body == 0
    assert "has a cortex, but the surface left of it for the IPC" in score.refused
    rim = float(re.search(r"its rim is ([-+]\d+) HU on what lies", score.refused).group(1))
    assert rim < 0.0  # a solid bar's rim is its blurred edge


def test_a_long_bone_whose_cortex_is_as_thick_as_a_real_shafts_keeps_its_ipc():
    """A long bone 15 mm in radius whose cortex is 6.75 mm thick (a tibia's or femur's shaft; the family draws 1-4 mm),
    with a 1,915 HU bracket resting on it (family seed 2 with those overrides): the cortex read under the IPC is that
    of a bone (+413 HU measured, against its object's +1,050 HU), far above a solid part's, and the IPC is the
    bone's."""
    from RAMSICPRegistrationLib.image.ipc_self_check import UNDER_SAMPLES, cortex_under

    overrides = {"bone": "long", "bone_radius_mm": 15.0, "cortex_mm": 6.75, "end_in_view": False}
    volume, truth = make_family_ct(2, "full", overrides=overrides)
    image, score = run(volume, truth)
    assert not score.refused and score.ipc_on_body == 0 and score.ipc_on_bone >= 0.99 * score.ipc_points
    segmentation, points = image.segmentation, image.surface.points
    points = points[:: max(1, len(points) // UNDER_SAMPLES)]
    vertices = volume.ras_to_ijk_points(points) - segmentation.origin
    assert np.median(cortex_under(segmentation.smoothed, vertices, volume.spacing)) > 300.0


def test_a_bar_held_by_a_plastic_plate_larger_than_the_soft_tissue_size_is_linked_to_its_spheres():
    """Fresh wide seed 61019 at 62 HU of noise: an 8.7 mm square bar of 1,485 HU (as bright as the cortex, 1,573 HU)
    resting on a flat bone 9.6 mm thick in air, held by a plastic plate of 119 HU (below the 200 HU threshold) that
    also holds the four spheres. The plate, 177 cm^3, was larger than the dim region the spheres' dim parts could be
    (150 cm^3, set for soft tissue), so the bar was not linked to them and stayed with the bone: 1,464 of the 4,748 IPC
    points were on it, with exit 0. Every dim region reached from the spheres leads on now (soft tissue meets the bone
    over too wide an area to link it): the bar is cut off the bone, and the IPC is the bone's."""
    overrides = {**wide_bracket_overrides(61019), "noise_hu": 62.0}
    volume, truth = make_family_ct(61019, "full", overrides=overrides)
    image, score = run(volume, truth)
    assert not score.refused and score.found == score.visible == 4 and score.false == 0
    assert score.ipc_on_body == 0 and score.ipc_on_bone == score.ipc_points > 2000
    assert image.segmentation.body is not None and image.segmentation.body.any()


def test_a_rod_dimmer_than_the_cortex_resting_on_the_bone_is_left_out_of_the_ipc():
    """Fresh wide seed 57010 at 62 HU of noise: a 9 mm round rod of 875 HU resting on a fibula whose cortex is
    1,543 HU, its frame cut off: no opening parts a rod as thick as the bone, and under that noise no level follows
    it, so 2,241 of the 7,042 IPC points were on it, exit 0. Under the rod's surface the CT has no cortex, solid 3-6 mm
    in and dimmer than the bone's (``solid_patches``): measured, 1,849 of them left out, 392 left (where it meets the
    bone), none of the bone's 4,801 lost, 94.9 % of the bone covered as before."""
    volume, truth = make_family_ct(57010, "full", overrides={**wide_bracket_overrides(57010), "noise_hu": 62.0})
    _, score = run(volume, truth)
    assert not score.refused and score.ipc_on_bone >= 4800 and score.coverage > 0.94
    assert score.ipc_on_body < 0.1 * score.ipc_points


@pytest.mark.parametrize("seed, noise_hu, covered", [(62035, 62.0, 0.93), (51047, None, 0.89)])
def test_a_bracket_no_opening_parts_from_the_bone_is_taken_off_whole_as_the_solid_part_it_is(seed, noise_hu, covered):
    """No sphere says where the body is (all cut by the field of view, or hidden), and the object is the bone with a
    solid bracket resting on it: fresh wide seed 62035 at 62 HU of noise, a 14 mm rod of 527 HU on a long bone 17.6 mm
    thick (cortex 773 HU); wide seed 51047, a 7.7 mm bar of 1,251 HU on a flat bone 8.6 mm thick. The bracket is found
    as a solid part, but the bone's core is within its reach at every opening and no plateau is read across the cut:
    both were refused, with 24.9 and 26 cm^3 of bone in view. The solid part taken off whole leaves the bone (measured:
    12,267 and 9,274 IPC points, all on the bone, 94.5 and 90.8 % of it covered)."""
    overrides = wide_bracket_overrides(seed)
    if noise_hu is not None:
        overrides["noise_hu"] = noise_hu
    volume, truth = make_family_ct(seed, "full", overrides=overrides)
    image, score = run(volume, truth)
    assert not score.refused and score.ipc_on_body == 0 and score.ipc_on_bone == score.ipc_points > 5000
    assert score.coverage >= covered
    assert image.segmentation.body is not None and image.segmentation.body.any()


def test_the_thin_pieces_of_a_frame_are_not_taken_off_whole_leaving_the_rest_of_it_for_the_bone():
    """Family seed 59001: a 1,345 HU plate with its plastic spheres sunk into it (none found) and an 8.5 mm bracket of
    465 HU inserted into a long bone. Its solid parts are three 4 mm bars of the plate, found at an opening of 2 mm;
    taken off whole, they left the plate with the bone, and its surface was the IPC (31,115 points, none on the bone).
    Only parts 5.5 mm thick or more are taken off so: no IPC point is the plate's (the CT is refused, as before)."""
    volume, truth = make_family_ct(59001, "full")
    _, score = run(volume, truth)
    assert score.ipc_on_body == 0 and score.ipc_on_bone == score.ipc_points


def test_a_body_object_the_spheres_miss_is_not_taken_for_bone_less_its_solid_parts():
    """Wide seed 55023: three spheres found on 1,592 HU posts and a 321 HU star frame, a flat bone beside them. An
    object of the body's that the spheres' seeds miss has solid parts; taken off whole, they left the rest larger than
    the bone, and its surface was the IPC (8,671 points, none on the bone, exit 0). Where spheres say where the body
    is, solid parts are not taken off whole: the IPC is the bone's, as before (15,729 points, all on it)."""
    volume, truth = make_family_ct(55023, "full", overrides=wide_bracket_overrides(55023))
    _, score = run(volume, truth)
    assert not score.refused and score.found == score.visible == 3
    assert score.ipc_on_body == 0 and score.ipc_on_bone == score.ipc_points > 10000
