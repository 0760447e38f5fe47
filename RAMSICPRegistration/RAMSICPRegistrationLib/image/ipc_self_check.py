"""The IPC checked against the reference body before it leaves: it must not hold a marker sphere's surface.

The bone's recognition (``bone_recognition``) decides which object is bone; if it ever takes the reference body
for bone (issue 27: the IPC written was the body's surface, with exit 0), the IPC holds the surface of the
marker spheres the detector found. A bone's surface can come near a sphere only from one side: a plane tangent
to the sphere's shell covers at most a sixth of the directions from its centre (the cone of half-angle
atan(sqrt((r + t)^2 - r^2) / r) = 37 degrees for r = 5.75 mm and t = ``SHELL_MM``, widened by ``CONE_DEG``), while a
sphere's own surface covers most of them (less its post's foot, or a frame it is sunk into).

When no object has a cortex, the bone's recognition takes the largest thick object without spheres, with a
warning; beside a marker sphere, in voxels fine enough to show a cortex, such an object solid through (its rim
brighter than its inside by less than ``bone_recognition.SOLID_CONTRAST_HU``) is the reference body's frame or
bracket, not a bone (``solid_body_taken_for_bone``; family seed 16078: a tibia's end wholly outside the round
field of view, the IPC was the 707 HU star frame's, with exit 0). Beside means within a post's reach of a sphere
(``SPHERE_REACH_MM``): a flat bone whose cancellous inside is nearly as bright as its cortex (rim +48 HU), 64-92 mm
from the spheres, is no frame of theirs (family seed 18066 was refused with 46 cm^3 of bone in view). With no
marker sphere found at all, nothing says where the body is: such an object is refused when its rim is dimmer than its
inside (``RIM_DIMMER_HU``), which no bone's is.

With no sphere paired with the tool nor tied by its distances, the IPC is searched for spheres the detector could
not see (``unfound_spheres_in_surface``): balls of the marker's radius whose surface it holds (``surface_balls``, and
the coverage above), two or more at one of the tool's pairwise marker distances from each other. Spheres sunk into a
plate brighter than they are stand out of it as caps on both sides, the object's outer surface (family seed 40192
with wide brackets: its IPC was the plate's, 23,454 of its 23,688 points on the body, exit 0). A bone has no two
round ends of the marker's radius at one of the tool's distances.

The object taken for bone may have a cortex and still give an IPC that is not the bone's: a bar or bracket joined
to it (one object, which no cut parted) keeps its surface where the bone's own is left out, next to a pin's metal,
on inner walls, at the field of view's edge (fresh wide seed 61018 at 62 HU of noise: a 16.4 mm square bar of
1,000 HU inserted into a long bone's end, 9.3 cm^3 of it in view with a pin in it; the object's rim was +670 HU on
its inside, and 11,467 of the 11,469 IPC points were on the bar, with exit 0). So the cortex is read again under the
IPC itself (``solid_under_surface``): across each sampled point, the CT's mean ``RIM_UNDER_MM`` in (the cortex)
against its mean ``INSIDE_UNDER_MM`` in (a thick cortex's far part and the marrow or cancellous bone beyond it; a
bar's own inside). A bone's rim is brighter than that by a share of its object's rim contrast (``UNDER_SHARE``; a
family long bone given a 6.75 mm cortex, as a real shaft has, by 413 HU, a tube with a 7 mm cortex by 788-816 HU:
the tests'); 61018's bar's is dimmer, by 33 HU.
"""

import logging
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from ..core.marker_geometry import at_pairwise_distances
from ..io.ndi_tools import MARKER_DIAMETER_MM
from .bone_recognition import SOLID_CONTRAST_HU, SOLID_MAX_VOXEL_MM, is_solid
from .ct_segmentation import along_gradient, downhill
from .marker_spheres import direction_coverage
from .surface_balls import find_balls

logger = logging.getLogger(__name__)

#: IPC points within this distance (mm) of a sphere's shell (|p - c| - r) are on its surface.
SHELL_MM = 1.5
#: A direction from the centre is covered when an IPC point on the shell lies within this angle of it (degrees).
CONE_DEG = 10.0
#: A sphere whose shell holds IPC points over this fraction of the directions from its centre is in the IPC.
MAX_COVERAGE = 0.4
#: ... and at least this many points (a speck of noise on the shell is not a sphere's surface).
MIN_POINTS = 30
#: A frame holds its spheres on posts: a solid object no sphere centre comes within this far (mm) of is not the
#: body's frame (posts up to 25 mm long, and the sphere's radius).
SPHERE_REACH_MM = 35.0
#: With no marker sphere found, an object taken for bone without a cortex whose rim is dimmer than its inside by more
#: than this (HU) is refused: a bone's cortex is its brightest layer, a solid frame's rim is its blurred edge. Family
#: seed 40133 with wide brackets: plastic spheres sunk into a 1,369 HU plate, a 2,495 HU bar resting on 0.9 cm^3 of
#: fibula in view; the plate (rim -22 HU) was taken for bone and the IPC was its surface (29,749 points, none on the
#: bone, exit 0). 16078's star frame: -172 HU. A flat bone whose cancellous inside is nearly as bright as its cortex
#: keeps a rim brighter than it (18066: +48 HU).
RIM_DIMMER_HU = 0.0


#: The cortex under an IPC point: the CT's mean this far in (mm, from and to) ...
RIM_UNDER_MM = (0.5, 2.5)
#: ... against its mean this far in (mm): past a cortex 10 mm thick (a femur's shaft, at its thickest), the marrow
#: or cancellous bone is in the mean; a bar 12 mm across and more is itself all through it.
INSIDE_UNDER_MM = (3.0, 12.0)
#: ... read every this many mm, at up to this many of the IPC's points.
UNDER_STEP_MM = 0.5
UNDER_SAMPLES = 4000
#: The IPC is over solid material when that contrast (its median) is below ``bone_recognition.SOLID_CONTRAST_HU`` and
#: below this share of the object's own rim contrast. A solid part's is at or below 0 (its rim's first samples lie in
#: the blur of its edge; 61018's bar: -33 HU against the object's +670 HU). A bone's, read across a surface where a
#: thin cortex is blurred into a bright inside, can be a small share of its object's: +34 and +36 HU against +192 and
#: +215 HU in family seeds 12041 and 12078 (flat bones with 1.3-1.9 mm of cortex round cancellous bone 280-290 HU
#: dimmer), the lowest of 700 family CTs (the 500 of the table, 120 wide at 62 HU of noise, 80 fresh) among those
#: whose object's rim is under 750 HU (above it, SOLID_CONTRAST_HU is the lower limit); at 0.25 of it, 12078 was
#: refused with 38 cm^3 of bone in view and 12041, looked at again on finer grids, kept 986 of its 40,720 points.
UNDER_SHARE = 0.1


@dataclass(frozen=True)
class SphereInSurface:
    """A marker sphere whose surface the IPC holds: its number (0 when not numbered), centre (3,) RAS mm, the
    fraction of directions from its centre the IPC covers, and the IPC points on its shell."""

    number: int
    centre: np.ndarray
    coverage: float
    points: int


def spheres_in_surface(points, spheres, radius_mm=MARKER_DIAMETER_MM / 2.0):
    """The marker ``spheres`` (objects with ``centre`` (3,) RAS mm and ``number``) whose surface the IPC ``points``
    (N, 3) RAS mm holds: over ``MAX_COVERAGE`` of the directions from the centre covered by IPC points within
    ``SHELL_MM`` of the shell of radius ``radius_mm``. Returns a list of SphereInSurface (empty when the IPC is
    clear of the reference body's spheres)."""
    points = np.asarray(points, dtype=np.float64)
    if not len(points) or not len(spheres):
        return []
    tree = cKDTree(points)
    found = []
    for sphere in spheres:
        centre = np.asarray(sphere.centre, dtype=np.float64)
        near = points[tree.query_ball_point(centre, radius_mm + SHELL_MM)]
        offsets = near - centre
        on_shell = offsets[np.abs(np.linalg.norm(offsets, axis=1) - radius_mm) <= SHELL_MM]
        if len(on_shell) < MIN_POINTS:
            continue
        coverage = direction_coverage(on_shell, cone_deg=CONE_DEG)
        if coverage > MAX_COVERAGE:
            found.append(SphereInSurface(int(getattr(sphere, "number", 0)), centre, coverage, len(on_shell)))
    return found


def unfound_spheres_in_surface(points, triangles, tool_markers, radius_mm=MARKER_DIAMETER_MM / 2.0):
    """Marker spheres the IPC holds though no sphere was found there (the module docstring): the balls of
    ``radius_mm`` on the IPC mesh (``points`` (N, 3) RAS mm, ``triangles`` (T, 3)) whose shell it covers over
    ``MAX_COVERAGE`` of the directions, when two or more lie within PAIRING_TOLERANCE_MM of one of the pairwise
    distances of the tool's markers (``tool_markers`` (K, 3) mm). Returns a list of SphereInSurface (number 0) of
    those at such distances, empty otherwise."""
    if triangles is None or len(points) == 0:
        return []
    balls = [_Ball(centre) for centre in find_balls(points, triangles, radius_mm)]
    held = spheres_in_surface(points, balls, radius_mm)
    return [held[i] for i in at_pairwise_distances([item.centre for item in held], tool_markers)]


@dataclass(frozen=True)
class _Ball:
    """A ball found on the IPC, as ``spheres_in_surface`` takes it."""

    centre: np.ndarray
    number: int = 0


def describe_unfound(found):
    """The refusal's words for ``unfound_spheres_in_surface``'s list."""
    balls = ", ".join(
        f"({', '.join(f'{value:.0f}' for value in item.centre)}) mm ({100 * item.coverage:.0f} % of it)"
        for item in found
    )
    return (
        f"no marker sphere was found, but the surface taken for the bone holds {len(found)} balls of the marker "
        f"spheres' size at the reference body's distances from one another: {balls}; they are its spheres, sunk into "
        "its frame or plate, so the object taken for bone is the reference body and no IPC is written: check that "
        "the bone is in the field of view, or segment the bone by hand"
    )


def describe(found):
    """The refusal's words for ``spheres_in_surface``'s list."""
    spheres = ", ".join(
        f"{'marker ' + str(item.number) if item.number else 'a sphere'} at "
        f"({', '.join(f'{value:.0f}' for value in item.centre)}) mm ({100 * item.coverage:.0f} % of it)"
        for item in found
    )
    return (
        f"the surface taken for the bone holds the surface of the reference body's marker sphere(s): {spheres}; the "
        "object taken for bone is the reference body, so no IPC is written: check the threshold (--threshold "
        "auto) and that the bone is in the field of view, or segment the bone by hand"
    )


def bone_verdict_in_fine_voxels(volume, segmentation):
    """The ``bone_recognition.ObjectVerdict`` of the object taken for bone when the voxels resolve a cortex
    (``SOLID_MAX_VOXEL_MM`` or finer); None in coarser ones, or with no recognition."""
    recognition = segmentation.recognition
    if recognition is None or volume.spacing.max() > SOLID_MAX_VOXEL_MM + 1e-6:
        return None
    return recognition.verdict


def solid_body_taken_for_bone(volume, segmentation, spheres):
    """The refusal's words when the object taken for bone has no cortex and is solid (``is_solid``) in voxels of
    ``SOLID_MAX_VOXEL_MM`` or finer, beside marker ``spheres`` (any found), or with its rim dimmer than its inside
    (``RIM_DIMMER_HU``) when none is found: the reference body's frame or bracket. None otherwise (a bone with a
    cortex, coarse voxels that blur a cortex away, a solid object far from the spheres)."""
    verdict = bone_verdict_in_fine_voxels(volume, segmentation)
    if verdict is None or verdict.verdict != "bone without a cortex" or not is_solid(verdict.cortex_hu):
        return None
    if not len(spheres):
        if verdict.cortex_hu >= -RIM_DIMMER_HU:
            return None
        beside = "dimmer on its rim than inside, which no bone is, and no marker sphere was found"
    elif _distance_to_object(volume, segmentation, verdict.label, spheres) > SPHERE_REACH_MM:
        return None
    else:
        beside = f"beside {len(spheres)} marker sphere(s) found"
    return (
        f"no object in the CT has a cortex, and the one taken for bone ({verdict.describe()}) is solid, {beside}: it "
        "is the reference body's frame or bracket, so no IPC is written; check that the bone is in the field of view "
        "and that the threshold is below its cortex (--threshold auto)"
    )


def _distance_to_object(volume, segmentation, label, spheres):
    """The shortest distance (mm) from a sphere's centre to a voxel of the object ``label`` of the segmentation."""
    voxels = np.argwhere(segmentation.labels == label) + segmentation.origin
    if not len(voxels):
        return float("inf")
    centres = np.array([sphere.centre for sphere in spheres]).reshape(-1, 3)
    return float(cKDTree(volume.ijk_to_ras_points(voxels)).query(centres)[0].min())


def cortex_under(image, vertices, spacing):
    """(M,) HU: the cortex under surface points, vertices (M, 3) (fractional indices in ``image``, a denoised CT of
    voxels ``spacing`` (3,) mm): the image's mean RIM_UNDER_MM in along its gradient (up it: into the bone) less its
    mean INSIDE_UNDER_MM in, each read every UNDER_STEP_MM. A tube of cortex 7 mm thick round marrow: 8.5 of the
    inside's 19 samples are cortex, so the rim is brighter by 10.5/19 of the cortex's rise over the marrow; a solid
    bar: 0."""
    vertices = np.asarray(vertices, dtype=np.float64)
    inward = -downhill(image, vertices, spacing)
    rim, inside = (
        along_gradient(image, vertices, inward, spacing, np.arange(low, high + 1e-6, UNDER_STEP_MM)).mean(axis=0)
        for low, high in (RIM_UNDER_MM, INSIDE_UNDER_MM)
    )
    return rim - inside


def solid_under_surface(volume, segmentation, points):
    """The refusal's words when the IPC ``points`` (N, 3) RAS mm lie over solid material though the object taken for
    bone has a cortex (the module docstring): the median of ``cortex_under`` over up to UNDER_SAMPLES of them, in
    the segmentation's denoised CT, is below ``bone_recognition.SOLID_CONTRAST_HU`` and below UNDER_SHARE of the
    object's rim contrast. None otherwise, in voxels coarser than SOLID_MAX_VOXEL_MM (they blur a cortex away), and
    when the object has no cortex (``solid_body_taken_for_bone`` reads that one)."""
    verdict = bone_verdict_in_fine_voxels(volume, segmentation)
    if verdict is None or verdict.verdict != "bone" or not len(points):
        return None
    points = np.asarray(points, dtype=np.float64)[:: max(1, len(points) // UNDER_SAMPLES)]
    vertices = volume.ras_to_ijk_points(points) - segmentation.origin
    contrast = float(np.median(cortex_under(segmentation.smoothed, vertices, volume.spacing)))
    logger.debug(
        "the cortex under the IPC: %+.0f HU over %d points (its object's rim: %+.0f HU)",
        contrast,
        len(points),
        verdict.cortex_hu,
    )
    if not is_solid(contrast, min(SOLID_CONTRAST_HU, UNDER_SHARE * verdict.cortex_hu)):
        return None
    return (
        f"the object taken for bone ({verdict.describe()}) has a cortex, but the surface left of it for the IPC (the "
        f"rest lies next to metal, on inner walls or at the field of view's edge) has none: its rim is {contrast:+.0f} "
        f"HU on what lies {INSIDE_UNDER_MM[0]:.0f}-{INSIDE_UNDER_MM[1]:.0f} mm under it (the median over "
        f"{len(points):,} of its points), a solid part's, the reference body's bracket joined to the bone; no IPC is "
        "written: scan the bone with the pin or bracket out of the field of view, or segment the bone by hand"
    )
