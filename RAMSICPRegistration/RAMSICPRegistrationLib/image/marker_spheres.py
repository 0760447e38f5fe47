"""Automatic marker-sphere centres in the CT (the paper places them by hand and names that its main error).

Nothing is assumed about which bright object is the bone, which part of the reference body is brightest, or that
the spheres are above the bone threshold: real reference bodies have posts and frames brighter or dimmer than their
spheres, plates the spheres touch, brackets that join the frame to the bone, and spheres from plastic to metal.

1. **Candidates: where the CT has the surface of a ball of the marker's radius** (``sphere_candidates``: a Hough
   transform on a coarse grid of the whole denoised CT, every object included, the bone's too).
2. **Fit on the sphere's own edge, ray by ray.** From a candidate's centre, ``RAYS`` rays are cast through the
   sphere's surface; along each, the edge is where the denoised CT falls through half-way between the sphere's
   inside (read in a shell clear of a stem in its centre) and that ray's own outside, 2 to 2.5 mm beyond the
   radius: air on most rays, a dimmer post or plate the sphere touches or is sunk into on others, so every edge
   point is a half-maximum point, unbiased by blur, whatever the surroundings. Rays whose outside is about as
   bright as the sphere, or brighter (its post, a bright frame), give no edge. A robust sphere fit
   (``fit_sphere``) on the edge points, repeated from the new centre, gives the centre, the radius and the
   residual. On a sphere seen over less than ``COVERAGE_LIMIT`` with a piece of its surface hidden (sunk into a
   post, plate or ring), or less than ``HIDDEN_BORDER_SEEN`` with an edge that fits it within
   ``HIDDEN_BORDER_FIT_MM``, the centre is fitted again without the edges within ``HIDDEN_BORDER_DEG`` of that piece,
   which its blur pushes out.
3. **Status**, for every sphere:

   * ``ok``: radius within 0.6 mm of the nominal, RMS residual under 0.2 mm, at least 85 % of its surface seen
     (75 % when its edge fits the sphere within ``CLEAN_FIT_MM``, or within ``HIDDEN_FIT_MM`` with the fitted radius
     within ``HIDDEN_RADIUS_MM`` of the nominal: a thick post as bright as the sphere hides the rest), no larger
     than the nominal by ``SWOLLEN_MM`` when a tenth of it or more is hidden, nor by ``ROUGH_SWOLLEN_MM`` with an
     RMS over ``ROUGH_FIT_MM``, and wholly inside the field of view;
   * ``partial``: part of the surface is missing (Fig. 4a's defects, a frame it is sunk into), or it is cut by the
     field of view (the edge of the volume, or padding outside the reconstruction, <= -1500 HU): its centre rests
     on what remains; or its edge is pushed out unevenly (larger than the nominal, ``ROUGH_SWOLLEN_MM``);
   * ``deformed``: the radius or the residual is off: the sphere is not round in the image.

   A candidate whose fit is far from any sphere (radius off by more than ``NOT_A_SPHERE_MM``, or less than
   ``MIN_COVERAGE`` of a surface) is not a marker and is dropped.
4. **Pairing with the tool** (``core.marker_geometry.pair_by_geometry``): the tool's inter-marker distances choose
   its markers among the spheres found and number them (a pairing that holds fewer than ``MIN_ROUND_PAIRED``
   round spheres, clean or partial, numbers none: spots that fit no sphere cannot number the others); a sphere
   that fits no marker (a spare sphere, a round bone feature) is left unnumbered; a marker not found is located
   where the others put it (``MarkerDetection.missing``), and said to be inside or outside the field of view. When
   no sphere pairs, the candidates, and then the spots where the body is a ball thick (``thick_spots``: spheres
   sunk into a brighter frame), that the tool's distances pair say where the reference body is
   (``MarkerDetection.tied``, status 'hidden': for the bone's recognition only, never usable).

Only ``ok`` spheres paired with a marker feed the coarse registration unless the user accepts the others.
"""

import logging
from dataclasses import dataclass, replace

import numpy as np
from scipy import ndimage, optimize, sparse
from scipy.sparse import csgraph

from ..core.marker_geometry import PAIRING_TOLERANCE_MM, at_pairwise_distances, pair_by_geometry
from ..io.ndi_tools import MARKER_DIAMETER_MM
from .sphere_candidates import find_sphere_candidates
from .thick_spots import thick_spots

logger = logging.getLogger(__name__)

RADIUS_TOLERANCE_MM = 0.6
#: A sphere whose clean edges lie off it (outliers of the fit) on more than this fraction of its rays is partial
#: (twice this when at least 90 % of its surface is seen or the rest fits it within CLEAN_FIT_MM: a thick post's
#: junction, a frame it is sunk into, streaks put some edges off; a cap cut off leaves its rays hollow, MAX_MISSING).
MAX_OFF_SPHERE = 0.08
RESIDUAL_LIMIT_MM = 0.2
#: A sphere seen over less than this fraction of its surface is partial: its centre is less sure ...
COVERAGE_LIMIT = 0.85
#: ... unless it is seen over at least this fraction and its edge fits the sphere within CLEAN_FIT_MM (RMS). A thick
#: post and the frame hide up to a fifth of a marker: seen over 77-84 % with an RMS of 0.025-0.05 mm, the family of
#: reference-body CTs' spheres fit within 0.03 mm (``reference_ct_family`` seeds 4078, 7100, 7140); the one such
#: sphere found 0.20 mm off, by a 7 mm post, had an RMS of 0.12 mm (seed 6180).
SEEN_CLEANLY = 0.75
CLEAN_FIT_MM = 0.06
#: ... or within HIDDEN_FIT_MM when its fitted radius is also within HIDDEN_RADIUS_MM of the nominal (as round as 99 %
#: of the clean spheres in 13 family batches). Noise and partial volume alone widen the RMS of a sphere as bright as
#: the post it stands on to 0.07-0.10 mm (family seed 23015: 238 HU spheres on 243 HU posts of 5.7 mm, seen over
#: 82-84 %, 0.06-0.07 mm off; a held-out plate's 195 HU spheres under 58 HU of noise: 0.07 mm RMS, 0.02-0.08 mm off).
#: Over the 6,402 spheres fitted in 13 family batches and 90 ring, plate and star draws, the 43 true markers seen
#: over 75-85 % that this takes were at most 0.111 mm off; a fit whose radius is off by 0.15 mm (a cap damaged, or
#: streaks bending the edge) was up to 0.148 mm off, and one with a wider RMS (0.10-0.12 mm) up to 0.132 mm.
HIDDEN_FIT_MM = 0.10
HIDDEN_RADIUS_MM = 0.12
#: A sphere seen over less than SWOLLEN_COVERAGE whose fitted radius exceeds the nominal by more than SWOLLEN_MM is
#: partial: the blur of the frame or post it is sunk into pushes its edges out, and its centre with them. A blurred
#: ball's half-max edge lies inside its surface, never outside: of the 1,120 clean spheres paired in 400 family CTs
#: (12000-13099, and 40000-40199 with wide brackets), 1,119 were fitted 0.009-0.20 mm short of the nominal radius.
#: The one longer (wide seed 40088: a 517 HU sphere sunk into a 104 HU star, seen over 86 %, radius +0.10 mm, RMS
#: 0.16 mm) was 0.27 mm off. A sphere seen nearly whole keeps its status (a ball larger than the tool's says so),
#: unless its edge is rough too (ROUGH_FIT_MM, below).
SWOLLEN_COVERAGE = 0.9
SWOLLEN_MM = 0.05
#: A sphere fitted larger than the nominal by more than ROUGH_SWOLLEN_MM with an RMS over ROUGH_FIT_MM is partial,
#: however much of it is seen: its edge is pushed out, and not evenly (metal streaks, what it touches), so its centre
#: is not sure; it is round enough to be numbered by the tool's distances. Fresh wide seed 58026 at 62 HU of noise:
#: 131 HU plastic spheres on 7.8 mm posts of 2,851 HU, two of them seen over 92.5 %, radius +0.04 and +0.06 mm, RMS
#: 0.15 and 0.14 mm, were given usable 0.37 and 0.29 mm off. Of the other 238 usable spheres of 90 wide CTs at 62 HU
#: (57000-57029, 58000-58059), one was fitted at the nominal (+0.001 mm, RMS 0.14 mm, 0.07 mm off: 58043), the rest
#: 0.02-0.13 mm short of it; none of the 1,337 usable spheres of the table's 500 CTs was fitted longer than it.
ROUGH_SWOLLEN_MM = 0.02
ROUGH_FIT_MM = 0.10
#: A sphere whose rays find its usual surroundings (air) within its radius, not a post or frame, on more than this
#: fraction of them is partial: a part of it is missing (a 4 mm cap is a fifth of the rays).
MAX_MISSING = 0.05
#: A sphere with more than MAX_INWARD of its edges INWARD_MM or more inside the fitted sphere is partial: the flat face
#: of a cap cut off, too shallow (2-3 mm) for its rays to find air within the radius, whose rim the robust fit half
#: follows (family seed 17022: 5.8 % of the edges, the centre 0.20 mm off, the fit's RMS 0.058 mm). Over the 1,209
#: usable spheres with no cap missing in 14000-17099 (four batches), at most 1.8 % of the edges lie that far in
#: (streaks, a frame's blur); 12 of the 13 usable ones with a cap missing have more (0.02-0.20 mm off).
INWARD_MM = 0.3
MAX_INWARD = 0.04
#: A sphere whose clean edge comes in pieces (rays ISLAND_NEIGHBOUR_DEG apart or nearer are neighbours; pieces of at
#: least ISLAND_MIN_RAYS count) and whose largest piece holds at least 1 - ISLAND_SHARE of it is partial when the
#: rest lies ISLAND_OUT_MM or more (mean) outside the sphere the largest piece fits alone: a cap seen through the hole
#: of a frame the sphere is sunk into, its edge pushed out by the frame's blur round it, which pulls the centre along
#: the hole's axis with a fit as clean as any (family seed 19038: a 618 HU plate round 1,775 HU spheres, such caps
#: 0.21-0.24 mm out, the centres 0.17-0.18 mm off, RMS 0.048-0.064 mm). Over the 3,165 spheres paired in nine
#: batches and 30 plates, the good spheres' pieces lay at most 0.11 mm out (19056, 32025).
ISLAND_NEIGHBOUR_DEG = 16.0
ISLAND_MIN_RAYS = 8
ISLAND_SHARE = 0.25
ISLAND_OUT_MM = 0.15
#: The centre of a sphere seen over less than COVERAGE_LIMIT, where a piece of its surface is hidden (rays without
#: an edge, pieces of at least ISLAND_MIN_RAYS), is fitted without the edges within HIDDEN_BORDER_DEG of the hidden
#: piece (when MIN_RAYS remain): next to a post, plate or ring the sphere is sunk into, that part's blur pushes the
#: edges out (up to 0.18 mm) and the centre towards it (held-out ring seed 41003: 2,930 HU spheres sunk in a 158 HU
#: ring, seen over 77-81 % with RMS 0.05 mm, 0.19-0.20 mm off; 0.08-0.09 mm without that border). Over the 5,397
#: spheres paired in 13 family batches and 300 ring, plate and star draws, the 299 ok ones seen < 85 % with a hidden
#: piece: mean error 0.027 -> 0.017 mm, none worse by more than 0.05 mm; the partial ones more than 0.15 mm off
#: 79 -> 33 of 610. Deformed spheres keep their whole edge (they are not round; their border says nothing). The
#: radius, residual and coverage reported stay those of the whole edge.
HIDDEN_BORDER_DEG = 25.0
#: ... and so is a sphere seen over less than HIDDEN_BORDER_SEEN whose edge fits it within HIDDEN_BORDER_FIT_MM (RMS):
#: the blur fills in the edge next to the hidden piece, and a sphere less than 80 % bare can be seen over 85-90 %
#: (wide seed 41003: 2,930 HU spheres sunk into a 158 HU star, seen over 88-89 %, RMS 0.06 mm, 0.16-0.17 mm off,
#: 0.07 mm without that border). Over the 1,218 spheres with a hidden piece fitted in the family's 12000-12199 and
#: its wide 40000-40199, the clean ones seen over 85-95 % (243): 0.019 -> 0.014 mm mean, 27 better by more than
#: 0.02 mm, one worse (12136: 0.016 -> 0.069 mm), the hidden ones among them (37) 0.032 -> 0.013 mm; the 23 with an
#: RMS over 0.08 mm: 8 better, 4 worse by more than 0.02 mm (40083: 0.14 -> 0.18 mm, false), so they keep their whole
#: edge.
HIDDEN_BORDER_SEEN = 0.95
HIDDEN_BORDER_FIT_MM = 0.08
#: A fit whose radius is off by more than this (mm), or that sees less than MIN_COVERAGE, is not a marker sphere
#: (rods of the frame fit spheres about 1.5 mm too small; the phantom's deformed sphere is 0.4 mm too large).
NOT_A_SPHERE_MM = 0.75
MIN_COVERAGE = 0.35
#: Rays cast from a candidate's centre to find its edge, sampled every RAY_STEP_MM; at least MIN_RAYS must find it.
RAYS = 400
RAY_STEP_MM = 0.1
MIN_RAYS = 60
#: A ray whose profile, SHOULDER_MM past its edge, is still more than SHOULDER_LIMIT of the contrast above its outside
#: and more than SHOULDER_RATIO times the sphere's median ray, crosses a thin layer of a dimmer part beyond the edge:
#: the rim of a sphere sunk into a frame as wide as it is (its edges 0.25-0.28 mm out there, 0.15 of the contrast
#: left against 0.04-0.08 elsewhere: family seed 10135).
SHOULDER_MM = 1.0
SHOULDER_LIMIT = 0.1
SHOULDER_RATIO = 2.0
#: A ray finds an edge where the sphere is at least this much brighter (HU) than the ray's own outside.
EDGE_CONTRAST_HU = 150.0
#: ... and whose outside is within this (HU, or a tenth of the contrast) of the sphere's usual surroundings.
STREAK_TOLERANCE_HU = 100.0
#: The sphere's brightness is read in this shell inside it (fractions of r): clear of a stem in its centre.
INSIDE_SHELL = (0.55, 0.85)
#: ... and its surroundings' in this one outside it (mm beyond r).
OUTSIDE_SHELL_MM = (1.5, 3.0)
#: A sphere is wholly in the field of view when it and this much more (mm) plus a voxel lie inside the volume's
#: voxel centres, with no padding (values at or below OUTSIDE_FIELD_OF_VIEW_HU) among them.
FIELD_OF_VIEW_MARGIN_MM = 0.25
#: Reconstructions pad the outside of their field of view (the corners of a round one) with a value no CT of
#: air reaches: -3024, -2048 HU. (Padding at -1024 looks like air voxel by voxel: it is told by its columns.)
OUTSIDE_FIELD_OF_VIEW_HU = -1500.0
#: An unpaired sphere this close (mm) to a missing marker's expected place is that marker, though it fits badly.
NEAR_EXPECTED_MM = 5.0
#: A pairing of the tool's markers with spheres that are not all clean holds at least this many round ones (clean or
#: partial): the numbers of the others rest on spots that fit no sphere.
MIN_ROUND_PAIRED = 2
#: ... and when it fits the tool's pattern only to more than this FRE (mm), the spots among them that fit their ball
#: loosely (``_fits_loosely``) must not be what numbers the others: fresh wide family seed 47003, two true spheres
#: (one clean, one damaged, 55.9 mm apart: which is which, their distance cannot say) and a spot cut by the field
#: of view (0.57 mm RMS off its ball) 48.8 and 102.7 mm from them, where the tool's third marker would be if the
#: two were the other way round (50.0 and 103.1 mm): FRE 1.05 mm, and the clean sphere numbered as the wrong marker.
#: The 85 pairings of wide seeds 40000-40099 fit to 0.18 mm at most, all right (none with a loose spot).
LOOSE_PAIRING_FRE_MM = 0.5
STATUSES = ("ok", "partial", "deformed")


@dataclass(frozen=True)
class MarkerSphere:
    """One fitted sphere: centre (3,) RAS mm, radius and RMS residual (mm), surface coverage (0..1), status.

    ``note`` says in words why a sphere is not ``ok``; ``label`` is the label of its voxels in the
    BoneSegmentation's labels (the bright object it belongs to, 0 when it is below the bone threshold, or its own
    voxels after ``label_sphere_voxels``); ``number`` is the tool marker it was paired with (1-based; 0 until
    paired, or when it cannot be); ``level_hu`` the iso-level its surface was fitted at.
    """

    centre: np.ndarray
    radius_mm: float
    residual_mm: float
    coverage: float
    status: str
    surface_points: int
    label: int
    note: str = ""
    number: int = 0
    level_hu: float = 0.0

    def to_dict(self):
        return {
            "number": self.number,
            "centre": self.centre.tolist(),
            "radius_mm": self.radius_mm,
            "residual_mm": self.residual_mm,
            "coverage": self.coverage,
            "status": self.status,
            "note": self.note,
            "surface_points": self.surface_points,
        }


@dataclass(frozen=True)
class MissingMarker:
    """A tool marker with no sphere found: where the other markers put it (RAS mm), whether the CT holds that
    centre, and whether a sphere there would be cut by the field of view (its centre in it, part of it out)."""

    number: int
    expected: np.ndarray
    in_field_of_view: bool
    cut_by_field_of_view: bool = False

    def to_dict(self):
        return {
            "number": self.number,
            "expected": self.expected.tolist(),
            "in_field_of_view": self.in_field_of_view,
            "cut_by_field_of_view": self.cut_by_field_of_view,
        }


@dataclass(frozen=True)
class MarkerDetection:
    """The marker spheres found, the number of candidates rejected, warnings; with a tool, its pairing
    (``core.marker_geometry.GeometricPairing``, or None when fewer than 3 spheres fit it) and the markers missing.
    ``tied``: when no 3 spheres could be paired, the spheres (clean or partial) that lie at one of the tool's
    pairwise marker distances from another: the reference body's, though too few or too sunk in to number; or, when
    there are none, the ball-shaped candidates the tool's geometry pairs (status 'hidden', never usable)."""

    spheres: tuple
    warnings: tuple
    rejected: int = 0
    pairing: object = None
    missing: tuple = ()
    tied: tuple = ()

    @property
    def ok_centres(self):
        """(K, 3) centres of the spheres with status 'ok'."""
        return np.array([sphere.centre for sphere in self.spheres if sphere.status == "ok"]).reshape(-1, 3)


def usable_spheres(spheres):
    """The spheres the coarse registration may use: status 'ok' and paired with a tool marker (``number`` > 0)."""
    return tuple(sphere for sphere in spheres if sphere.status == "ok" and sphere.number > 0)


def detect_marker_spheres(volume, segmentation, expected=4, diameter_mm=MARKER_DIAMETER_MM, tool_markers=None):
    """Find and fit the marker spheres anywhere in the CT; with ``tool_markers``, choose and number the tool's.

    Args:
        volume: the CTVolume that was segmented (its geometry and raw values).
        segmentation: BoneSegmentation (its denoised ``smoothed`` image over its ``box``, and its labels).
        expected: how many spheres the reference body has (``len(tool_markers)`` when they are given).
        diameter_mm: the spheres' diameter.
        tool_markers: (K, 3) the reference body's marker geometry (mm), or None.

    Returns:
        MarkerDetection; its warnings say when fewer or more spheres than expected were found, which marker is
        missing and where it should be, or when a sphere is partial or deformed, and what to do.
    """
    radius = diameter_mm / 2.0
    if tool_markers is not None:
        expected = len(tool_markers)
    spheres, rejected = [], 0
    candidates = find_sphere_candidates(volume, segmentation.smoothed, segmentation.origin, radius)
    for candidate in candidates:
        sphere = _fit_candidate(volume, segmentation, candidate.centre, radius)
        if sphere is None:
            rejected += 1
        else:
            spheres.append(sphere)
    spheres = _without_duplicates(spheres, radius)
    pairing, missing, warnings, tied = None, (), [], ()
    if tool_markers is not None:
        found = spheres
        spheres, pairing, missing, warnings, dropped = _pair_with_tool(volume, spheres, tool_markers, radius)
        rejected += dropped
        if pairing is None:
            tied = _tied_by_tool_distances(found, tool_markers) or _candidates_at_tool_distances(
                volume, segmentation, [candidate.centre for candidate in candidates], tool_markers, radius
            )
            if not tied:  # spheres sunk into a frame brighter than they are: where the body is a ball thick
                spots = list(thick_spots(volume, segmentation, radius))
                tied = _candidates_at_tool_distances(volume, segmentation, spots, tool_markers, radius)
    warnings = [sphere_warning(sphere) for sphere in spheres if sphere.status != "ok"] + warnings
    good = sum(sphere.status == "ok" and (tool_markers is None or sphere.number > 0) for sphere in spheres)
    if tool_markers is None and len(spheres) != expected:
        warnings.append(
            f"found {len(spheres)} marker-sphere candidates ({rejected} other bright spots rejected by their "
            f"shape), expected {expected}: check that the reference body is in the field of view, or place the "
            "missing centres by hand"
        )
    elif good < expected and (tool_markers is None or pairing is not None):
        warnings.append(f"only {good} of {expected} spheres are clean; the coarse registration needs at least 3")
    for warning in warnings:
        logger.info("marker detection: %s", warning)
    return MarkerDetection(tuple(spheres), tuple(warnings), rejected, pairing, tuple(missing), tuple(tied))


def _candidates_at_tool_distances(volume, segmentation, centres, tool_markers, radius):
    """When no sphere could be fitted where the tool's markers are (spheres sunk into the frame, their edges hidden):
    the ball-shaped candidates that the tool's geometry pairs (3 or more, ``pair_by_geometry``), as spheres of status
    'hidden' (not usable: for the bone's recognition only, which must know where the reference body is)."""
    if len(centres) < 3:
        return ()
    try:
        pairing = pair_by_geometry(centres, tool_markers)
    except ValueError:
        return ()
    return tuple(
        MarkerSphere(
            centre=np.asarray(centres[row], float),
            radius_mm=radius,
            residual_mm=float("nan"),
            coverage=0.0,
            status="hidden",
            surface_points=0,
            label=_label_at(volume, segmentation, np.asarray(centres[row], float)),
            note="a ball-shaped spot at the tool's distances from others, its edge not found",
        )
        for row in pairing.indices
        if row >= 0
    )


def _tied_by_tool_distances(spheres, tool_markers):
    """The spheres, clean or partial (not deformed), within PAIRING_TOLERANCE_MM of one of the tool's pairwise
    marker distances from another such sphere: two of the tool's markers (a round bump of bone is not at the tool's
    distance from a sphere of the marker's size), even when they cannot be numbered (fewer than 3 in view, or sunk
    into the frame)."""
    round_ones = [sphere for sphere in spheres if _is_round(sphere)]
    tied = at_pairwise_distances([sphere.centre for sphere in round_ones], tool_markers)
    return tuple(round_ones[i] for i in tied)


def sphere_warning(sphere):
    """What to tell the user about a sphere that is not ``ok``: which one, what is wrong, what to do."""
    where = f"({', '.join(f'{v:.1f}' for v in sphere.centre)}) mm"
    name = f"marker {sphere.number} at {where}" if sphere.number else f"the sphere at {where}"
    return (
        f"{name} is {sphere.status}: {sphere.note}; check it in the CT and move its centre by hand, or leave it "
        "out of the coarse registration"
    )


def fit_sphere(points, inlier_limit_mm=0.1):
    """Least-squares sphere through (N, 3) points, robust to a missing or added part of the surface.

    An algebraic fit starts a geometric fit with a Cauchy loss (scale ``inlier_limit_mm``); points within
    3 robust standard deviations (at least ``inlier_limit_mm``) are the inliers, and a plain least-squares fit
    on them gives the result.

    Returns:
        centre (3,), radius (mm), RMS residual of the inliers (mm), and the boolean inlier mask (N,).
    """
    centre, radius = _algebraic_fit(points)
    robust = optimize.least_squares(
        lambda p: np.linalg.norm(points - p[:3], axis=1) - p[3],
        np.append(centre, radius),
        loss="cauchy",
        f_scale=inlier_limit_mm,
    )
    residuals = np.linalg.norm(points - robust.x[:3], axis=1) - robust.x[3]
    spread = 1.4826 * np.median(np.abs(residuals - np.median(residuals)))
    keep = np.abs(residuals) <= max(3.0 * spread, inlier_limit_mm)
    refined = optimize.least_squares(
        lambda p: np.linalg.norm(points[keep] - p[:3], axis=1) - p[3], robust.x, method="lm"
    )
    centre, radius = refined.x[:3], abs(refined.x[3])
    rms = float(np.sqrt(np.mean((np.linalg.norm(points[keep] - centre, axis=1) - radius) ** 2)))
    return centre, float(radius), rms, keep


def sphere_values(spheres):
    """Labelmap value of each sphere: 1 + n for marker n, then the spheres not paired with a marker (2 + the
    highest marker number, ...); 1 is the bone."""
    count = max([sphere.number for sphere in spheres] + [0])
    values = []
    for sphere in spheres:
        count += 0 if sphere.number else 1
        values.append(1 + (sphere.number or count))
    return values


def sphere_labelmap(segmentation, spheres):
    """(I, J, K) labelmap of the whole CT: 1 for the bone, 1 + n for marker n's sphere (``sphere_values``)."""
    return segmentation.labelmap([sphere.label for sphere in spheres], sphere_values(spheres))


def label_sphere_voxels(volume, segmentation, spheres):
    """Give each sphere's own voxels a label of their own in ``segmentation.labels`` (in place), split from the
    posts and frame they touch, so a labelmap shows the spheres and not the whole reference body.

    A sphere's own voxels are those of its object within 1 mm of its fitted surface; a sphere below the bone
    threshold (label 0) gets the voxels above its fit's level there. A sphere that is its own connected
    component keeps its label. Returns the spheres with their labels.
    """
    labels = segmentation.labels
    next_label = int(labels.max()) + 1
    labelled = []
    for sphere in spheres:
        box, offsets = _local_box(volume, segmentation, sphere.centre, sphere.radius_mm + 1.0)
        if box is None:
            labelled.append(sphere)
            continue
        ball = np.linalg.norm(offsets, axis=-1) <= sphere.radius_mm + 1.0
        local = labels[box]
        if sphere.label > 0:
            own = ball & (local == sphere.label)
            if own.sum() == np.count_nonzero(labels == sphere.label):
                labelled.append(sphere)
                continue
        else:
            own = ball & (local == 0) & (segmentation.smoothed[box] >= sphere.level_hu)
        local[own] = next_label
        labelled.append(replace(sphere, label=next_label))
        next_label += 1
    return tuple(labelled)


def _local_box(volume, segmentation, centre, half_mm):
    """The box (slices into the segmentation's arrays) around an RAS point reaching ``half_mm`` every way, and
    its voxels' RAS offsets from the point (I, J, K, 3); (None, None) outside the segmentation's box."""
    full, ras = volume.voxels_within(centre - half_mm, centre + half_mm)
    if full is None:
        return None, None
    origin, shape = segmentation.origin, np.array(segmentation.smoothed.shape)
    low = np.array([s.start for s in full]) - origin
    high = np.array([s.stop for s in full]) - origin
    clipped_low, clipped_high = np.maximum(low, 0), np.minimum(high, shape)
    if (clipped_high - clipped_low < 2).any():
        return None, None
    trim = tuple(slice(a - b, c - b) for a, b, c in zip(clipped_low, low, clipped_high))
    return tuple(slice(a, b) for a, b in zip(clipped_low, clipped_high)), ras[trim] - centre


def _fit_candidate(volume, segmentation, centre, radius):
    box, offsets = _local_box(volume, segmentation, centre, radius + OUTSIDE_SHELL_MM[1] + 1.0)
    if box is None:
        return None
    image = segmentation.smoothed[box]
    distance = np.linalg.norm(offsets, axis=-1)
    inside = (distance >= INSIDE_SHELL[0] * radius) & (distance <= INSIDE_SHELL[1] * radius)
    outside = (distance >= radius + OUTSIDE_SHELL_MM[0]) & (distance <= radius + OUTSIDE_SHELL_MM[1])
    if not inside.any() or not outside.any():
        return None
    inside_hu = float(np.median(image[inside]))
    low = np.array([s.start for s in box]) + segmentation.origin
    directions = _fibonacci_directions(RAYS)
    for _ in range(4):
        previous = centre
        along, valid, hollow = _edges_along_rays(volume, image, low, centre, directions, radius, inside_hu)
        if valid.sum() < MIN_RAYS:
            return None
        points = centre + along[valid, None] * directions[valid]
        centre, fitted_radius, rms, keep = fit_sphere(points)
        if abs(fitted_radius - radius) > NOT_A_SPHERE_MM:
            return None
        if np.linalg.norm(centre - previous) < 0.005:
            break  # the rays from the new centre would find the same edges
    inliers = points[keep]
    coverage = direction_coverage(inliers - centre)
    if coverage < MIN_COVERAGE:
        return None
    off_sphere, missing = 1.0 - float(keep.mean()), float(hollow.mean())
    inward = float(np.mean(np.linalg.norm(points - centre, axis=1) < fitted_radius - INWARD_MM))
    status, note = _status(volume, centre, radius, fitted_radius, rms, coverage, off_sphere, missing, inward)
    if status == "ok":  # the pieces are looked for on clean spheres only: a millisecond each
        island = _island_out(inliers, np.nonzero(valid)[0][keep], directions)
        if island >= ISLAND_OUT_MM:
            status = "partial"
            note = (
                f"a part of its edge seen apart from the rest lies {island:.2f} mm outside the sphere the rest fits "
                "(a cap seen through a frame it is sunk into?)"
            )
    if status != "deformed" and _fitted_clear_of_hidden(coverage, rms):
        clear = _clear_of_hidden(directions, valid)[valid]
        if MIN_RAYS <= clear.sum() < len(clear):
            centre = fit_sphere(points[clear])[0]
    return MarkerSphere(
        centre=centre,
        radius_mm=fitted_radius,
        residual_mm=rms,
        coverage=coverage,
        status=status,
        surface_points=int(keep.sum()),
        label=_label_at(volume, segmentation, centre),
        note=note,
        level_hu=0.5 * (inside_hu + float(np.median(image[outside]))),
    )


def _edges_along_rays(volume, image, low, centre, directions, radius, inside_hu):
    """Where each ray from ``centre`` crosses the sphere's edge (mm from the centre), and which rays have one.

    Along each ray the image is sampled every RAY_STEP_MM from 2.5 mm inside the nominal radius to 2.5 mm outside;
    the edge is where it falls through half-way between the sphere's inside (``inside_hu``) and this ray's own
    outside (its samples 2 to 2.5 mm beyond the radius): air, a dimmer post or plate, or soft tissue. A ray whose
    outside is not at least EDGE_CONTRAST_HU darker (a post or frame as bright as the sphere, or brighter), or
    that leaves the CT, has none; nor has one whose profile lingers above its outside past the edge (SHOULDER_MM).
    """
    along = np.arange(radius - 2.5, radius + 2.5 + 1e-9, RAY_STEP_MM)
    ras = centre + along[None, :, None] * directions[:, None, :]
    ijk = volume.ras_to_ijk_points(ras.reshape(-1, 3)) - low
    profiles = ndimage.map_coordinates(image, ijk.T, order=1, mode="constant", cval=np.nan).reshape(ras.shape[:2])
    outside_hu = np.mean(profiles[:, along >= radius + 2.0], axis=1)
    # Each ray's own inside, just within the edge: a streak that adds to a ray adds to both its ends.
    own_inside = np.median(profiles[:, (along >= radius - 2.5) & (along <= radius - 1.5)], axis=1)
    level = 0.5 * (own_inside + outside_hu)
    valid = np.isfinite(profiles).all(axis=1) & (own_inside - outside_hu >= EDGE_CONTRAST_HU)
    with np.errstate(invalid="ignore"):  # rays that leave the CT are NaN, and invalid already
        valid &= np.abs(own_inside - inside_hu) <= 0.25 * (inside_hu - np.nanmedian(outside_hu))
    below = profiles < level[:, None]
    valid &= ~below[:, 0]
    first = np.argmax(below, axis=1)  # the first sample below the level, going out
    valid &= below.any(axis=1)
    # A clean edge: nothing much brighter than the sphere just inside it (a metal stem in a plastic sphere, whose blur
    # would push the edge out), and nothing back above the level outside it (a post or frame right beside it).
    inner = profiles[:, along <= radius - 1.0]
    with np.errstate(invalid="ignore"):
        valid &= np.max(inner, axis=1) <= inside_hu + 0.5 * (inside_hu - outside_hu)
    valid &= (below | (np.arange(len(along))[None, :] < first[:, None])).all(axis=1)
    # A ray whose outside is off the sphere's usual surroundings (air, mostly) by more than a tenth of the contrast
    # runs along a metal streak, which moves the edge: left out (the post's and frame's rays are left out above).
    usual = np.median(outside_hu[valid]) if valid.any() else np.nan
    valid &= np.abs(outside_hu - usual) <= max(STREAK_TOLERANCE_HU, 0.1 * (inside_hu - usual))
    rows = np.arange(len(directions))
    before, after = profiles[rows, np.maximum(first - 1, 0)], profiles[rows, first]
    fraction = np.clip((before - level) / np.maximum(before - after, 1e-6), 0.0, 1.0)
    edge = along[np.maximum(first - 1, 0)] + fraction * RAY_STEP_MM
    # A ray whose profile lingers above its outside past the edge crosses a thin layer of a dimmer part (a frame the
    # sphere is sunk into, as wide as the sphere): the layer's blur moves the edge out (SHOULDER_MM).
    past = (edge - along[0]) / RAY_STEP_MM + SHOULDER_MM / RAY_STEP_MM
    beyond = ndimage.map_coordinates(profiles, [rows, past], order=1, mode="nearest")
    with np.errstate(invalid="ignore", divide="ignore"):
        lingering = (beyond - outside_hu) / (own_inside - outside_hu)
    if valid.sum() >= MIN_RAYS:
        valid &= lingering <= max(SHOULDER_LIMIT, SHOULDER_RATIO * float(np.median(lingering[valid])))
    # Rays that find the sphere's usual surroundings (air) inside its radius as well as outside: no post or frame
    # hides the sphere there, part of it is missing.
    tolerance = max(STREAK_TOLERANCE_HU, 0.1 * (inside_hu - usual))
    with np.errstate(invalid="ignore"):
        hollow = (np.abs(own_inside - usual) <= tolerance) & (np.abs(outside_hu - usual) <= tolerance)
    return edge, valid, hollow


def _pieces(unit):
    """Connected pieces of the ray directions ``unit`` (N, 3): rays ISLAND_NEIGHBOUR_DEG apart or nearer are
    neighbours. Returns each ray's piece (N,) and the pieces' sizes."""
    near = sparse.csr_matrix(unit @ unit.T >= np.cos(np.radians(ISLAND_NEIGHBOUR_DEG)))
    _, piece = csgraph.connected_components(near, directed=False)
    return piece, np.bincount(piece)


def _fitted_clear_of_hidden(coverage, rms):
    """True when a sphere seen over ``coverage`` (fraction of its surface) with an edge that fits it within ``rms``
    (mm) is centred without the edges next to a hidden piece (HIDDEN_BORDER_DEG), when it has one."""
    return coverage < COVERAGE_LIMIT or (coverage < HIDDEN_BORDER_SEEN and rms <= HIDDEN_BORDER_FIT_MM)


def _clear_of_hidden(directions, valid):
    """Which rays (bool (RAYS,)) lie more than HIDDEN_BORDER_DEG from every hidden piece of the surface: rays
    without an edge (``valid`` False) in pieces of at least ISLAND_MIN_RAYS."""
    hidden = np.nonzero(~valid)[0]
    if len(hidden) == 0:
        return np.ones(len(directions), bool)
    piece, sizes = _pieces(directions[hidden])
    hidden = hidden[sizes[piece] >= ISLAND_MIN_RAYS]
    if len(hidden) == 0:
        return np.ones(len(directions), bool)
    nearest = np.max(directions @ directions[hidden].T, axis=1)  # cosine of the angle to the nearest hidden ray
    return nearest < np.cos(np.radians(HIDDEN_BORDER_DEG))


def _island_out(points, rays, directions):
    """How far (mm, mean) the clean edge ``points`` (N, 3) found along ``rays`` (N,) indices into ``directions``
    lie outside the sphere that their largest piece fits alone, when they come in pieces and the rest is at most
    ISLAND_SHARE of them; else 0.0."""
    piece, sizes = _pieces(directions[rays])
    largest = piece == np.argmax(sizes)
    if (sizes >= ISLAND_MIN_RAYS).sum() < 2 or largest.mean() < 1.0 - ISLAND_SHARE:
        return 0.0
    centre, radius, _, _ = fit_sphere(points[largest])
    return float(np.mean(np.linalg.norm(points[~largest] - centre, axis=1) - radius))


def _label_at(volume, segmentation, centre):
    index = np.rint(volume.ras_to_ijk_points(centre[None])[0]).astype(int) - segmentation.origin
    if (index < 0).any() or (index >= np.array(segmentation.labels.shape)).any():
        return 0
    return int(segmentation.labels[tuple(index)])


def cut_by_field_of_view(volume, centre, radius):
    """True when a sphere (centre (3,) RAS, radius mm) is not wholly in the CT's field of view: within
    ``FIELD_OF_VIEW_MARGIN_MM`` and a voxel of the volume's edge, or of padding outside the reconstruction."""
    reach = radius + FIELD_OF_VIEW_MARGIN_MM + float(volume.spacing.max())
    ijk = volume.ras_to_ijk_points(centre[None])[0]
    last = np.array(volume.voxels.shape) - 1
    if (np.minimum(ijk, last - ijk) * volume.spacing).min() < reach:
        return True
    box, ras = volume.voxels_within(centre - reach, centre + reach)
    near = np.linalg.norm(ras - centre, axis=-1) <= reach
    values = volume.voxels[box]
    if (values[near] <= OUTSIDE_FIELD_OF_VIEW_HU).any():
        return True
    # Padding at -1024 HU looks like air voxel by voxel, but its columns hold that one value in every slice (air
    # has noise): any such column by the sphere is the round field of view's outside.
    rows, columns = np.nonzero((near & (values <= -1024)).any(axis=2))
    for i, j in set(zip(rows + box[0].start, columns + box[1].start)):
        column = volume.voxels[i, j, :]
        if (column == column[0]).all():
            return True
    return False


def in_field_of_view(volume, point):
    """True when an RAS point (3,) lies among the CT's voxel centres and not in padding outside the reconstruction."""
    ijk = volume.ras_to_ijk_points(np.asarray(point, float)[None])[0]
    index = np.rint(ijk).astype(int)
    if (index < 0).any() or (index >= np.array(volume.voxels.shape)).any():
        return False
    return bool(volume.voxels[tuple(index)] > OUTSIDE_FIELD_OF_VIEW_HU)


def _status(volume, centre, radius, fitted_radius, rms, coverage, off_sphere, missing=0.0, inward=0.0):
    if cut_by_field_of_view(volume, centre, radius):
        return "partial", f"cut by the edge of the field of view, {100 * coverage:.0f} % of its surface seen"
    round_enough = abs(fitted_radius - radius) <= RADIUS_TOLERANCE_MM and rms <= RESIDUAL_LIMIT_MM
    if round_enough and missing > MAX_MISSING:
        return "partial", f"{100 * missing:.0f} % of its rays find air within its radius (a cap missing?)"
    if round_enough and inward > MAX_INWARD:
        return "partial", f"{100 * inward:.0f} % of its edge lies {INWARD_MM} mm or more inside it (a cap missing?)"
    if round_enough and off_sphere > MAX_OFF_SPHERE * (2.0 if coverage >= 0.9 or rms <= CLEAN_FIT_MM else 1.0):
        # Clean edges that are not on the sphere: a cap cut off (Fig. 4a), a dent; its centre may have moved.
        return "partial", f"{100 * off_sphere:.0f} % of the edge found lies off the sphere (a cap missing?)"
    if round_enough and coverage < SWOLLEN_COVERAGE and fitted_radius - radius > SWOLLEN_MM:
        return "partial", (
            f"radius {fitted_radius:.2f} mm (nominal {radius:.2f} mm) where {100 * (1 - coverage):.0f} % of it is "
            "hidden: what it is sunk into pushes its edge out"
        )
    if round_enough and fitted_radius - radius > ROUGH_SWOLLEN_MM and rms > ROUGH_FIT_MM:
        return "partial", (
            f"radius {fitted_radius:.2f} mm (nominal {radius:.2f} mm) and its surface {rms:.2f} mm RMS off a sphere: "
            "a blurred ball's edge lies inside its surface, so something (streaks, what it touches) pushes this "
            "one's out"
        )
    fits_as_clean = rms <= CLEAN_FIT_MM or (rms <= HIDDEN_FIT_MM and abs(fitted_radius - radius) <= HIDDEN_RADIUS_MM)
    if round_enough and (coverage >= COVERAGE_LIMIT or (coverage >= SEEN_CLEANLY and fits_as_clean)):
        return "ok", ""
    if round_enough:
        return "partial", f"only {100 * coverage:.0f} % of its surface is seen"
    return "deformed", (
        f"radius {fitted_radius:.2f} mm (nominal {radius:.2f} mm), surface {rms:.2f} mm RMS off a sphere"
    )


class TooFewRoundSpheres(ValueError):
    """The tool's distances pair spots of which fewer than MIN_ROUND_PAIRED fit a sphere (``_clean_first_pairing``)."""


def _pair_with_tool(volume, spheres, tool_markers, radius):
    """Number the spheres by the tool's markers (``pair_by_geometry``); returns (spheres in the tool's order, then
    unpaired clean ones; the pairing or None; the MissingMarkers; warnings; how many unpaired spheres were
    dropped)."""
    count = len(tool_markers)
    try:
        pairing = _clean_first_pairing(spheres, tool_markers)
    except ValueError as error:
        clean = [sphere for sphere in spheres if sphere.status == "ok"]
        why = f" ({error})" if isinstance(error, TooFewRoundSpheres) else ""
        return (
            clean,
            None,
            (),
            [
                f"{len(spheres)} sphere(s) found, fewer than 3 of them at the distances of the reference body's "
                f"{count} markers{why}: check that the reference body is in the field of view and that this is its "
                "tool (--tool), or place the centres by hand"
            ],
            len(spheres) - len(clean),
        )
    numbered, used = {}, set()
    for marker, row in enumerate(pairing.indices):
        if row >= 0:
            numbered[marker + 1] = replace(spheres[row], number=marker + 1)
            used.add(int(row))
    missing, warnings = [], []
    for marker in range(count):
        if marker + 1 in numbered:
            continue
        expected = pairing.expected[marker]
        near = [
            (float(np.linalg.norm(spheres[row].centre - expected)), row)
            for row in range(len(spheres))
            if row not in used
        ]
        distance, row = min(near) if near else (np.inf, -1)
        if distance <= PAIRING_TOLERANCE_MM:  # a flagged sphere where the clean ones put the marker: that marker
            numbered[marker + 1] = replace(spheres[row], number=marker + 1)
            used.add(row)
            continue
        if distance <= NEAR_EXPECTED_MM:
            # A sphere where the marker should be, off by more than the pairing allows: that marker, not round.
            sphere = spheres[row]
            note = f"{distance:.1f} mm from where the other markers put it" + (
                f"; {sphere.note}" if sphere.note else ""
            )
            numbered[marker + 1] = replace(sphere, number=marker + 1, status="deformed", note=note)
            used.add(row)
            continue
        in_view = in_field_of_view(volume, expected)
        cut = in_view and cut_by_field_of_view(volume, expected, radius)
        missing.append(MissingMarker(marker + 1, expected, in_view, cut))
        where = ", ".join(f"{value:.1f}" for value in expected)
        if cut:
            advice = (
                "inside the CT's field of view, but a sphere there reaches out of it (cut by its edge): scan the "
                "whole reference body, or place its centre by hand"
            )
        elif in_view:
            advice = (
                "inside the CT's field of view: check the CT there (a sphere hidden by metal, damaged, or too dim), "
                "or place its centre by hand"
            )
        else:
            advice = "outside the CT's field of view: scan the whole reference body, or go on with the others"
        warnings.append(f"marker {marker + 1} not found: the other markers put its centre at ({where}) mm, {advice}")
    if pairing.ambiguous:
        warnings.append(
            f"the spheres fit the reference body's geometry in two ways (FRE {pairing.fre_mm:.2f} and "
            f"{pairing.runner_up_fre_mm:.2f} mm): check which sphere is which marker"
        )
    if pairing.fre_mm > PAIRING_TOLERANCE_MM / 2:
        warnings.append(
            f"the sphere centres fit the reference body's geometry only to {pairing.fre_mm:.2f} mm (FRE): check "
            "which NDI tool is mounted"
        )
    others = [sphere for row, sphere in enumerate(spheres) if row not in used and sphere.status == "ok"]
    dropped = len(spheres) - len(used) - len(others)
    ordered = [numbered[number] for number in sorted(numbered)] + others
    return ordered, pairing, missing, warnings, dropped


def _clean_first_pairing(spheres, tool_markers):
    """``pair_by_geometry`` of the spheres with the tool, the clean ones first: when at least 3 clean spheres pair,
    that pairing stands (its rows those of ``spheres``), though flagged ones would pair more markers: the feet of
    the posts lie in the tool's pattern too, shifted by the posts' length, and fit as flagged spheres. Otherwise all
    the spheres are paired, and the pairing stands only when at least MIN_ROUND_PAIRED of the spheres it pairs are
    round (not deformed): two round ends of bone that fit no sphere (family seed 27015: a flat bone's rim, radius
    5.3 mm, 0.3 mm RMS off a sphere) lay at the tool's distances from one true sphere, and numbered it as the wrong
    marker, while the one other true sphere in view was left out. Raises ValueError as ``pair_by_geometry`` does,
    or TooFewRoundSpheres."""
    names = {"points_name": "the sphere centres found in the CT", "reference_name": "the reference body"}
    clean = [row for row, sphere in enumerate(spheres) if sphere.status == "ok"]
    if 3 <= len(clean) < len(spheres):
        try:
            pairing = pair_by_geometry([spheres[row].centre for row in clean], tool_markers, **names)
        except ValueError:
            pass
        else:
            rows = np.array([clean[i] if i >= 0 else -1 for i in pairing.indices])
            return replace(pairing, indices=rows)
    pairing = pair_by_geometry([sphere.centre for sphere in spheres], tool_markers, **names)
    round_paired = sum(_is_round(spheres[row]) for row in pairing.indices if row >= 0)
    if round_paired < MIN_ROUND_PAIRED:
        raise TooFewRoundSpheres(
            f"those at its distances are {round_paired} round sphere(s) and "
            f"{int((pairing.indices >= 0).sum()) - round_paired} spot(s) that fit no sphere"
        )
    loose = [int(row) for row in pairing.indices if row >= 0 and _fits_loosely(spheres[row])]
    if loose and pairing.fre_mm > LOOSE_PAIRING_FRE_MM:
        # The numbers would rest on spots that fit a ball only loosely and lie off the tool's pattern: they are
        # given only if the others pair without them.
        kept = [row for row in range(len(spheres)) if row not in loose]
        try:
            again = _clean_first_pairing([spheres[row] for row in kept], tool_markers)
        except ValueError:
            raise TooFewRoundSpheres(
                f"those at its distances fit it only to {pairing.fre_mm:.2f} mm (FRE), and {len(loose)} of them fit "
                f"a ball only to {max(spheres[row].residual_mm for row in loose):.2f} mm RMS: no number rests on such "
                "spots"
            ) from None
        return replace(again, indices=np.array([kept[row] if row >= 0 else -1 for row in again.indices]))
    return pairing


def _fits_loosely(sphere):
    """A flagged sphere whose surface lies off its ball by more than RESIDUAL_LIMIT_MM RMS: a spot cut by the field
    of view or a round end of something, whose centre may be off by a millimetre."""
    return sphere.status != "ok" and sphere.residual_mm > RESIDUAL_LIMIT_MM


def _is_round(sphere):
    """A sphere that fits a ball of the marker's size, clean or partial (not 'deformed'): a marker, seen whole or
    not; a spot that fits no sphere (a round end of bone) is deformed."""
    return sphere.status != "deformed"


def _without_duplicates(spheres, radius):
    """Two candidates that converged on one sphere: keep the one with more surface points."""
    kept = []
    for sphere in sorted(spheres, key=lambda s: -s.surface_points):
        if all(np.linalg.norm(sphere.centre - other.centre) > radius for other in kept):
            kept.append(sphere)
    return sorted(kept, key=lambda s: tuple(s.centre))


def _algebraic_fit(points):
    # |p|^2 = 2 c.p + (r^2 - |c|^2) is linear in c and the constant.
    design = np.hstack((2.0 * points, np.ones((len(points), 1))))
    solution, *_ = np.linalg.lstsq(design, np.sum(points**2, axis=1), rcond=None)
    centre = solution[:3]
    return centre, float(np.sqrt(max(solution[3] + centre @ centre, 1e-12)))


def _fibonacci_directions(count):
    """(count, 3) unit vectors spread evenly over the sphere (a Fibonacci lattice)."""
    index = np.arange(count) + 0.5
    polar = np.arccos(1.0 - 2.0 * index / count)
    azimuth = np.pi * (1.0 + 5.0**0.5) * index
    return np.column_stack((np.cos(azimuth) * np.sin(polar), np.sin(azimuth) * np.sin(polar), np.cos(polar)))


def direction_coverage(offsets, directions=200, cone_deg=20.0):
    """Fraction of evenly spread directions from the centre that have a surface point within ``cone_deg``."""
    unit = _fibonacci_directions(directions)
    offsets = offsets / np.linalg.norm(offsets, axis=1, keepdims=True)
    return float(np.mean(np.max(unit @ offsets.T, axis=1) >= np.cos(np.radians(cone_deg))))
