"""Which object in the CT is the bone: by what bone is, not by its size (issue 27).

A reference body can be larger and brighter than the piece of bone a C-arm CT holds, and joined to it by the
bracket that fixes it (the paper inserts an extending bracket into the porcine ilium). So the bone is recognised:

1. **Not the reference body.** Objects (connected components above the threshold) within a sphere's radius and
   1 mm of a marker sphere's centre (``marker_spheres``: spheres are looked for in every object) hold the body.
2. **Cut off a bracket.** An object that holds spheres may hold the bone too, joined by a bracket. With the
   spheres' balls taken out, it is opened (morphologically) by balls of growing radius, the smallest first so
   that as little bone as possible is lost: the first radius at which a part far from every sphere and
   plausibly bone survives is just over the bracket's (the neck the opening cut). That part, and the thin bits
   hanging off it that do not lead to a sphere, is the bone; the rest (bracket, frame, posts) is the body, and
   IPC points within that radius and a cell of it are left out (the bracket's stub, the corner the blur fills).
   The largest opening is 7 mm; on a bone thick enough, the cut is made again with 9 and 11 mm too, for a bracket
   wider than 14 mm, and taken when what only the first kept is solid (``_ObjectShape.cut_off_body``).
   Where no sphere says where the body is (its spheres out of view or sunk into its frame) or the spheres miss a
   part of it, the opening tells it too: a **solid** part (its rim no brighter than its inside: a frame, a
   bracket) that falls apart from a part with a cortex is the body's, and so is a solid part that the bone's core,
   as the openings shrink, grows far from the bone kept so far (a frame the seeds miss, or thinner than the bracket
   that joins it: no opening splits it off; with no sphere anywhere, the bone's core alone is grown). A bracket
   nearly as thick as the bone is not parted from it by any opening: the body is then **followed by its material**
   into what the cut kept (``body_material``: a bracket's or a frame's inside is a plateau of one brightness that
   goes on across the cut; a bone's inside is one too, but its cortex surrounds it), and where no opening parts
   them at all, from the body's seeds (or, where none is seen, its solid parts) into an object that looks like bone
   as a whole; the small pieces its plateaus split off the bone (posts of another material) go with it. Where no
   sphere says where the body is and neither an opening nor a plateau parts a solid part at least 5.5 mm thick from
   the bone (a bracket resting on a bone nearly as thick), the part is taken off whole (``without_solid_parts``).
   Where the body's seeds may lie in the bone (spheres only tied by the tool's distances, one of them perhaps a
   bracket's round end in the marrow; a dim part that leads on into the bone), a cut that leaves a piece with a
   cortex round its inside on the body's side (for tied spheres: larger than the bone kept) is no cut.
3. **Plausibly bone:** at least ``MIN_BONE_MM3`` (cavities filled), at least ``MIN_HALF_THICKNESS_MM`` from its
   surface somewhere, and a **cortex**: its rim brighter than its inside by ``CORTEX_CONTRAST_HU`` (marrow or
   cancellous bone inside a cortical shell; a rod, plate or block of one material has a rim no brighter than its
   inside). The largest such object is the bone. If none has a cortex, the largest thick one without spheres is
   taken, with a warning (or the part a cut took off the body, if its rim is brighter than a solid part's: a flat
   bone whose cancellous inside is nearly as bright as its cortex); if there is none at all, ``ValueError`` says
   what was found and what to do.

Shapes are measured on a grid of about ``CELL_MM`` (block means of the denoised CT), which the cut's margin covers.
"""

import logging
from dataclasses import dataclass
from functools import partial

import numpy as np
from scipy import ndimage

from ..io.ndi_tools import MARKER_DIAMETER_MM
from .body_material import BAND_HU, NOISY_HU, averaged_means, levels_among, means_noise_hu, plateau_from_nearest
from .components import boxes_and_sizes
from .morphology import (
    block_max,
    dilate,
    dilate_by_cube,
    largest_piece,
    open_by_cube,
    reaching_no_side,
    unblock,
)
from .parallel import in_parallel
from .plugs import PLUG_MM, between_sides, closed_holes, inside_pieces
from .sphere_candidates import block_means

logger = logging.getLogger(__name__)

#: The grid the shapes are measured on (mm, about).
CELL_MM = 1.0
#: ... coarser for a large object, so that its grid has about this many cells at most.
MAX_CELLS = 250_000
#: ... or this many, when no bone is found on the coarser grids (``ct_pipeline.process_ct`` looks once more): cells of
#: 1.4 x 1.4 x 1.8 mm on an object that held a flat bone 9.7 mm thick and the plate its 8.4 mm bar joins (wide family
#: seed 40193, 60 cm^3 of bone in view) left no opening between the bar's half width and the bone's half thickness,
#: and the CT was refused; on its voxels (0.7 x 0.7 x 0.9 mm) the bar is cut off (37,117 IPC points, all on the bone).
FINE_MAX_CELLS = 1_000_000
#: A hole in an object's walls is plugged up to twice ``plugs.PLUG_MM`` wide, or else twice this (mm), when that gives
#: it a cortex (``_ObjectShape._plugged``): a 10.9 mm bracket of 157 HU inserted into a long bone cut by the field of
#: view opened its marrow (fresh wide seed 51017: 6.9 cm^3 of cortex 3 mm thick, refused with 19 cm^3 of bone in
#: view; plugged so, 6,944 IPC points, all on the bone).
WIDE_PLUG_MM = 8.0
#: Smallest bone (mm^3, cavities filled): a 16 mm piece of a thin shaft.
MIN_BONE_MM3 = 1500.0
#: A bone is at least twice this thick somewhere (mm).
MIN_HALF_THICKNESS_MM = 2.0
#: A cortex: the rim at least this much brighter (HU) than the inside.
CORTEX_CONTRAST_HU = 150.0
#: An inside darker than this (HU) is air, not marrow: a pocket the field of view's edge (which the fill takes for
#: the CT's side) closes with a frame or plate, or a loop of frame, bracket and bone. An object with a cortex round
#: marrow is taken for the bone before one round air (family seed 13116: a metal plate's "cortex" of +3,122 HU
#: round air outranked the bone), but one round air is bone still when no other is (13019: a flat bone in a loop).
ENCLOSED_AIR_HU = -900.0
#: A core (an opening's centre) smaller than this (mm^3) opens to no bone.
MIN_CORE_MM3 = 100.0
#: ... but where no seed says where the body is, a solid piece the bone's core grows far from the bone
#: (``_solid_parts_grown``) is the body's from this (mm^3): a short rod's core beyond ROD_TO_MM is small (family seed
#: 35090: an 8.3 mm rod standing 27 mm out of a flat bone, no sphere found, 57 mm^3 at an opening of 2.75 mm, rim -9
#: HU on its inside; kept with the bone, 806 IPC points on it). Where seeds hold the body, pieces that small may be
#: the bone's (wide seed 40277: one set apart 37-58 mm from the body, 4.7 % of the bone's coverage lost).
MIN_GROWN_SOLID_MM3 = 40.0
#: The cortex is looked for this deep (mm) under the object's surface at the threshold, which lies out in the blur
#: beyond the cortex's peak when the threshold is low against the bone's surroundings (bone in soft tissue).
RIM_MM = 2.5
#: Opening radii (mm) tried to cut a bracket off the bone, smallest first.
OPENING_RADII_MM = (1.5, 2.0, 2.75, 3.5, 4.5, 5.5, 7.0)
#: ... and, on an object thick enough, a second cut with these too, for a bracket wider than 14 mm on a bone thicker
#: still (``wide_bracket_overrides``: a 15-18 mm bar on a 23-27 mm long bone was kept with the bone whole, 2,000-7,400
#: IPC points on it). Its first core, a thick part of the bone, can reach the body's seeds at the next opening and
#: keep only that part (wide seed 40071: a 12.5 mm rod resting on a tibia, 2 IPC points left): it is taken only on
#: the terms of ``_ObjectShape.cut_off_body``.
WIDE_OPENING_RADII_MM = (9.0, 11.0)
#: ... and only when what the first cut kept more is solid by this much (HU, its rim brighter than its inside by less):
#: the wide brackets kept so were -54 to +3 HU; a piece of an ilium's cancellous crest, +60 HU (family seed 13040:
#: 2.8 cm^3 of the bone lost, 90 -> 84 % covered, with SOLID_CONTRAST_HU).
WIDE_SOLID_CONTRAST_HU = 30.0
#: A rod set apart at an opening leaves a stub on the bone, and the IPC points within that opening (and a cell or two)
#: of the body were left out; at most ROD_MARGIN_MAX_MM (mm) of it now: the stub itself is taken off the bone
#: (``bracket_stub``, ``rod_stub``), and a margin as wide as a wide bracket's opening left out a ring as wide round
#: its foot (``wide_bracket_overrides`` seed 40010: a 15 mm square bar resting on a 23 mm long bone, its coverage
#: 91 % with 3.5 mm, 86 % with 7 mm).
ROD_MARGIN_MAX_MM = 3.5
#: The bracket, as the bone's core grows it out of the bone kept so far, crosses the band ROD_FROM_MM to ROD_TO_MM
#: from it.
ROD_FROM_MM = 1.5
ROD_TO_MM = 7.5
#: Cells darker than this (HU) at their brightest are a round field of view's padding (-1024 HU or lower), not air.
PADDING_HU = -1010.0
#: A part whose rim is less than this brighter (HU) than its inside is solid (a frame, a bracket), not bone.
SOLID_CONTRAST_HU = 75.0
#: ... told only with voxels this fine (mm) or finer.
SOLID_MAX_VOXEL_MM = 1.0
#: A solid part the bone's core grows is told at this opening (mm) or more: a core at 1.5 mm is 3 mm thick, a
#: cortex wall's, whose rim and inside are the same cortex (family seed 13116: 204 mm^3 of a tibia's 2.7 mm cortex of
#: 848 HU, rim -7 HU on its inside, was set apart, 13 points of the bone's coverage lost).
SOLID_GROWN_MIN_OPENING_MM = 2.0
#: The solid parts are taken off the bone whole, where no opening parts them (``_ObjectShape.without_solid_parts``),
#: only when found at this opening (mm) or more: parts at least 5.5 mm thick, a bracket. Thinner ones are the pieces
#: of a frame, and the rest of the body stays with the bone when they go (family seed 59001: three 4 mm bars of a
#: 1,345 HU plate, its plastic spheres sunk into it; the plate kept with the bone, and its surface was the IPC, 31,115
#: points, none on the bone). The brackets so taken off were found at 2.75-7 mm (62035, 41013, 51047, 60021, 45026).
WHOLE_PART_MIN_OPENING_MM = 2.75
#: The largest cores an opening leaves that are weighed, and the cells of a solid one that seed the body.
MAX_CORES = 4
SOLID_SEEDS = 40
#: At most this many objects (the largest) are looked at.
MAX_OBJECTS = 12
#: The body is followed by its material (``body_material``) into the bone a cut kept: the levels are read among the
#: bone's cells at least MATERIAL_DEEP_MM under the object's surface (out of the blur) and within MATERIAL_LEVELS_MM of
#: the body; a plateau is taken when it comes within MATERIAL_TOUCH_MM of the body (the blur between two materials,
#: which no plateau holds, lies between them), at most MATERIAL_STEPS times (a frame, then its bracket).
MATERIAL_DEEP_MM = 2.0
MATERIAL_LEVELS_MM = 8.0
MATERIAL_TOUCH_MM = 3.0
MATERIAL_STEPS = 3
#: The bone's inside level is read this far (mm) from the body at least.
MATERIAL_FAR_MM = 10.0
#: A plateau holding more than this share of the inside of the bone that far from the body is the bone's inside (the
#: wide CT 40173: a 223 HU bracket inserted into a flat bone whose inside is 257 HU, one plateau with it, 0.92 of that
#: inside; the brackets and frames of 40002, 40096, 40197, 40231, 40245, 40248 and 40271, kept with the bone by the
#: cut, 0.00-0.29: their own part far from the body).
MATERIAL_FAR_INSIDE_SHARE = 0.5
#: A plateau taken takes the cells round it this deep (cells along the grid's axes) too: the blur at its edge.
MATERIAL_BLUR_CELLS = 2
#: The pieces a following split off the bone are looked for again with the bone opened by a cube this many cells wide
#: (odd): a rim of blur a cell or two thick may still join them (``_without_pieces_split_off``).
SPLIT_OPENING_CELLS = 3
#: A plateau the bone left surrounds (outside it, less than this fraction of the ring MATERIAL_RING_MM round it) and no
#: darker than that ring is the bone's inside (its marrow or cancellous bone under the cortex), not the body's. In the
#: wide CTs 40002, 40197, 40245 and 40248, the brackets' and frames' plateaus had 0.13-0.47 of their ring outside the
#: bone (40248's rod, inserted, none, but its ring 650 HU darker than it); the bones' insides 0.00-0.01, their ring
#: 133-148 HU brighter (the cortex). Over the 338 family CTs a cut reaches, the plateaus so surrounded had rings
#: +99 HU or more above them when they were the bone's inside, -46 HU or less when the body's: a ring within 80 HU
#: below the part is its own blur (wide seed 40255 drawn with 62 HU of noise: a 953 HU bar, its ring 900 HU).
MATERIAL_OPEN_FRACTION = 0.1
MATERIAL_RING_MM = 2.5
#: A plateau whose cavities (filled) are more than this share of its own cells, at the level of the bone's inside, is
#: a shell: the bone's cortex round its inside, solid where it is thick (family seed 12094: a long bone's 1,334 HU
#: cortex, its cavity 0.49 of it, was taken for the body and the tibia refused). A cavity at another level is the
#: body's own part (held-out wide draw 3009: a bar's 955 HU end inserted into its 1,795 HU plate, 2.03 times the plate
#: kept with the bone, the bone's inside -63 HU).
MATERIAL_CAVITY_SHARE = 0.25
#: ... and where the bone a plateau is taken from has a rim dimmer than a cortex, the rest keeps this share of it at
#: least (its contrast, HU): a bracket's plateau taken leaves the bone's rim as it was (49030: +96, +96, +95, +93 HU
#: after each of three plateaus); the bone's own would leave a rim dimmer, and one that was no bone's before is none
#: (wide seed 40131: the posts' plateau taken from +69 HU left +87 HU, mostly a 13.6 mm bar of 612 HU; taken for the
#: bone, 80 % of the IPC was the bar's). ``_keeps_the_rim``.
KEPT_RIM_SHARE = 0.9


@dataclass(frozen=True)
class ObjectVerdict:
    """What one object was taken for: ``label``, its filled volume (mm^3), half its largest thickness (mm), its
    cortex contrast (HU, None when it is too thin to tell), ``spheres``: how many of the reference body's contacts
    it holds (marker spheres, posts' feet, dim parts' contacts, a solid part's seeds), and ``verdict``;
    ``air_inside``: its filled inside is air (ENCLOSED_AIR_HU), not marrow."""

    label: int
    volume_mm3: float
    half_thickness_mm: float
    cortex_hu: float
    spheres: int
    verdict: str
    air_inside: bool = False

    def to_dict(self):
        return {
            "label": self.label,
            "volume_mm3": self.volume_mm3,
            "thickness_mm": 2.0 * self.half_thickness_mm,
            "cortex_hu": self.cortex_hu,
            "reference_body_contacts": self.spheres,
            "verdict": self.verdict,
            "air_inside": self.air_inside,
        }

    def describe(self):
        if self.cortex_hu is None:
            cortex = "no inside to tell a cortex"
        else:
            cortex = f"rim {self.cortex_hu:+.0f} HU on its inside" + (" (air)" if self.air_inside else "")
        # Not "marker spheres": a solid part gives many contacts (wide seed 41013: 1 sphere found, 46 contacts).
        held = f", {self.spheres} contact(s) with the reference body (spheres, posts, parts)" if self.spheres else ""
        return f"{self.volume_mm3 / 1000.0:.1f} cm^3, {2 * self.half_thickness_mm:.0f} mm thick, {cortex}{held}"


@dataclass(frozen=True)
class BoneRecognition:
    """The bone's ``label``; ``body``: booleans over the segmentation's box of the reference body's voxels in the
    bone's object (None when the body is apart), with ``body_margin_mm``; ``objects``: an ObjectVerdict each;
    ``warnings``; ``has_cortex``: False when no object had a cortex and the bone was taken without one;
    ``body_followed``: the voxels of ``body`` its material took from what the opening kept with the bone (None when
    none: ``_ObjectShape._follow_body_material``)."""

    label: int
    body: np.ndarray
    body_margin_mm: float
    objects: tuple
    warnings: tuple = ()
    has_cortex: bool = True
    body_followed: np.ndarray = None

    @property
    def verdict(self):
        """The bone's ObjectVerdict (None when it is not among ``objects``)."""
        return next((verdict for verdict in self.objects if verdict.label == self.label), None)


def recognise_bone(volume, segmentation, spheres, spheres_sure=True, max_cells=MAX_CELLS):
    """Recognise the bone among a segmentation's objects (see the module docstring).

    Args:
        volume: the CTVolume (its geometry).
        segmentation: a BoneSegmentation from ``ct_segmentation.threshold_ct`` (labels and denoised image over
            its box).
        spheres: the marker spheres of the reference body (``MarkerSphere``; their ``centre`` and ``radius_mm``).
        spheres_sure: False when the spheres are only tied by the tool's distances (``MarkerDetection.tied``: none
            numbered). A sphere-like spot of the bone's object may be among them (family seed 27033: the round end of
            a 10.8 mm bracket in a tibia's marrow, at one of the tool's distances from two true spheres), and a cut
            with it as the body's takes the bone for the body: then no cut may leave a piece with a cortex round its
            inside on the body's side larger than the bone it keeps (a spot of the bone tied by chance costs the bone
            only the piece round it: 25005).
        max_cells: the most cells an object's grid has (MAX_CELLS, or FINE_MAX_CELLS for a second look).

    Raises:
        ValueError: no object is plausibly bone; the message lists what was found.
    """
    # Each object's voxel count and box, once: a pass over the whole segmentation, one slab per core.
    slices, sizes = boxes_and_sizes(segmentation.labels)
    census = _Census(sizes, slices, {}, max_cells)
    held = _held_by_spheres(volume, segmentation, spheres, census)
    plain = _body_seeds(volume, segmentation, spheres, census, held, dim_links=False)
    unsure = set() if spheres_sure else {label for label, held in plain.items() if held}
    if not _within_reach_of_dim_parts(volume, segmentation, spheres, plain, census):
        # no object the dim parts could reach but the body's
        return _recognise(volume, segmentation, plain, census, unsure=unsure)
    try:
        linked = _body_seeds(volume, segmentation, spheres, census, held)
        reached = {label for label, held in linked.items() if held and not plain[label]}  # by the dim parts only
        recognition = _recognise(volume, segmentation, linked, census, reached, unsure)
    except ValueError:
        # The dim parts may have led on through soft tissue to the bone (a dim bracket ending in it): once more
        # with the spheres and their posts' feet alone.
        return _recognise(volume, segmentation, plain, census, unsure=unsure)
    if recognition.has_cortex:
        return recognition
    # Led on to the bone, the dim parts may leave no object with a cortex but a piece of the body (24095: a 145 HU
    # bracket resting on a tibia under 70 HU of noise, its specks above the threshold joined to the bone): the
    # spheres and their posts' feet alone may tell the bone, with its cortex.
    try:
        alone = _recognise(volume, segmentation, plain, census, unsure=unsure)
    except ValueError:  # nothing plausibly bone that way: the first recognition, with its warning
        return recognition
    return alone if alone.has_cortex else recognition


@dataclass(frozen=True)
class _Census:
    """The segmentation's objects: ``sizes`` (L + 1,) voxels per label (0 for the background), ``slices`` their boxes
    (``ndimage.find_objects``, label 1 first), ``shapes`` {label: _ObjectShape} as they are measured (a second
    recognition, with other seeds, measures none again), on grids of at most ``max_cells`` cells."""

    sizes: np.ndarray
    slices: list
    shapes: dict
    max_cells: int = MAX_CELLS


def _within_reach_of_dim_parts(volume, segmentation, spheres, seeds, census):
    """True when an object large enough to be bone and holding no seed lies within DIM_BODY_REACH_MM of the
    spheres' box: only then can dim posts or a dim frame lead to it (``_dim_links``), which is worth the look."""
    if not spheres:
        return False
    centres = volume.ras_to_ijk_points(np.array([sphere.centre for sphere in spheres])) - segmentation.origin
    reach = (DIM_BODY_REACH_MM + MARKER_DIAMETER_MM) / volume.spacing
    low, high = centres.min(axis=0) - reach, centres.max(axis=0) + reach
    voxel_mm3 = float(np.prod(volume.spacing))
    for label, region in enumerate(census.slices, start=1):
        if region is None or seeds.get(label) or label not in segmentation.object_labels:
            continue
        if np.prod([s.stop - s.start for s in region]) * voxel_mm3 < MIN_BONE_MM3:
            continue
        start, stop = np.array([s.start for s in region]), np.array([s.stop for s in region])
        if (start <= high).all() and (stop >= low).all():
            return True
    return False


def _recognise(volume, segmentation, held, census, reached=(), unsure=()):
    """The recognition, knowing where each object is the body's (``held``: ``_body_seeds``); ``reached``: the
    objects only the dim parts lead to (a dim bracket may end in the bone): their cut must leave no bone-like piece
    on the body's side; ``unsure``: those held by spheres only tied by the tool's distances (one may be a spot of the
    bone): their cut must leave none larger than the bone it keeps."""
    voxel_mm3 = float(np.prod(volume.spacing))
    sizes, slices = census.sizes, census.slices
    objects = sorted(segmentation.object_labels, key=lambda label: -sizes[label])[:MAX_OBJECTS]
    weighed = [label for label in objects if _weighed(sizes[label], voxel_mm3)]
    unmeasured = [label for label in weighed if label not in census.shapes]
    shapes = in_parallel(
        *[
            partial(_ObjectShape, volume, segmentation, label, slices[label - 1], census.max_cells)
            for label in unmeasured
        ]
    )
    census.shapes.update(zip(unmeasured, shapes))
    # The solid parts of the objects that may hold a bone and a body, measured at once too.
    in_parallel(
        *[census.shapes[label].solid_parts for label in weighed if _may_hold_a_body(census.shapes[label], held[label])]
    )
    verdicts, found = [], []
    unseen = not any(held.values())  # no sphere, post or dim part says where the body is
    for label in objects:
        if label not in weighed:  # even filled it cannot be a bone
            verdicts.append(ObjectVerdict(label, sizes[label] * voxel_mm3, 0.0, None, len(held[label]), "too small"))
            continue
        shape = census.shapes[label]
        if held[label] and shape.filled_mm3 < 2.0 * MIN_BONE_MM3:
            verdict, bone = shape.verdict(len(held[label])), None  # too small to hold a bone besides
        elif held[label]:
            # The body's solid parts (a frame the spheres' seeds do not reach) are the body's too, unless with them
            # no bone is left (a solid bracket resting on the bone: its core's reach takes in the bone's).
            solid = shape.solid_parts()
            guard = {"no_bone_on_body": label in reached, "no_more_bone_on_body": label in unsure}
            verdict, bone = shape.cut_off_body(held[label] + solid, **guard)
            if solid and bone is None:
                verdict, bone = shape.cut_off_body(held[label], **guard)
            if bone is None:  # no opening parts them: a bracket nearly as thick as the bone, followed from the seeds
                verdict, bone = shape.followed_from_seeds(held[label], **guard) or (verdict, bone)
        else:
            verdict, bone = shape.verdict(0), None
            solid = shape.solid_parts() if verdict.verdict.startswith("bone") else []
            if solid:  # a body whose spheres are out of view or sunk into its frame, joined to the bone
                # The solid parts are the body's by their rim alone: a cut that leaves more bone on their side than
                # it keeps went through the bone (fresh wide seed 51047: a 7.7 mm bar resting on a flat bone 8.6 mm
                # thick, the bone's core within the bar's reach from 3.5 mm down; 3.8 cm^3 of 29 kept, the rest
                # taken for the body, and no IPC).
                verdict, bone = shape.cut_off_body(solid, no_more_bone_on_body=True)
                if bone is None:
                    verdict, bone = shape.followed_from_seeds(solid, no_bone_on_body=True) or (verdict, bone)
                if bone is None and unseen:  # no opening parts them, nothing to follow: the solid parts taken off whole
                    # Only where no sphere, post or dim part says where the body is: where they do, an object of the
                    # body's that they miss (a frame, its posts) is no bone less its solid parts (wide seed 55023: its
                    # 1,592 HU posts and 321 HU frame so taken, larger than the flat bone beside them, were the IPC,
                    # 8,671 points, none on the bone).
                    verdict, bone = shape.without_solid_parts(solid) or (verdict, bone)
            elif unseen and verdict.verdict.startswith("bone") and shape.filled_mm3 >= 2.0 * MIN_BONE_MM3:
                # No sphere says where the body is and no opening splits a solid part off: a frame thinner than
                # the bracket that joins it (32007: a 5 mm plate round its spheres on a 6.9 mm bracket inserted into
                # a flat bone) is told by the solid part the bone's core grows beyond the bracket.
                verdict, bone = shape.cut_off_body([])
        verdicts.append(verdict)
        if verdict.verdict.startswith("bone"):
            found.append((verdict, bone, shape))
    with_cortex = [entry for entry in found if entry[0].verdict == "bone"]
    round_marrow = [entry for entry in with_cortex if not entry[0].air_inside]
    with_cortex = round_marrow or with_cortex  # a rim round air is bone only when no rim round marrow is found
    warnings, has_cortex = [], bool(with_cortex)
    if not with_cortex:
        if not found:
            raise ValueError(_nothing_like_bone(verdicts, segmentation.threshold_hu))
        warnings.append(
            "no object in the CT has a cortex (a rim brighter than its inside); the bone is taken to be the "
            "largest thick object without marker spheres: check the IPC"
        )
        with_cortex = found
    verdict, cut, shape = max(with_cortex, key=lambda entry: entry[0].volume_mm3)
    body, margin = (None, 0.0) if cut is None else (shape.body_in_box(cut), cut.margin_mm)
    followed = None if cut is None or cut.followed is None else shape.cells_in_box(cut.followed) & body
    logger.info("bone: object %d (%s)", verdict.label, verdict.describe())
    return BoneRecognition(verdict.label, body, margin, tuple(verdicts), tuple(warnings), has_cortex, followed)


def _body_seeds(volume, segmentation, spheres, census, held, dim_links=True):
    """{label: [(point (3,) RAS, reach mm)]}: where each object is the reference body's for sure.

    An object within a sphere's radius and 1 mm of a sphere's centre holds it (a sphere above the threshold, or its
    bright post), and one a post stands on (``held``: ``_held_by_spheres``); an object the spheres reach through
    dimmer parts of the body (``_dim_links``: posts or a frame below the threshold) is the body where they meet it.
    """
    spheres_held, feet = held
    seeds = {label: list(points) for label, points in spheres_held.items()}
    # The spheres' objects (theirs, or their posts'), and those their posts stand on (a dim frame's specks above the
    # threshold split its dim parts: the dim parts start from each of them too).
    holding = [label for label, points in seeds.items() if points] + [label for label, _ in feet]
    links = _dim_links(volume, segmentation, spheres, census.sizes, holding) if dim_links else []
    for label, point in links + feet:
        seeds[label].append((point, 1.0))
    return seeds


def _held_by_spheres(volume, segmentation, spheres, census):
    """({label: [(centre (3,) RAS, reach mm)]}, feet): the objects within a sphere's radius and 1 mm of its centre,
    and the posts' feet (``_post_feet``: [(label, point)])."""
    seeds = {label: [] for label in range(len(census.sizes))}
    for sphere in spheres:
        reach = sphere.radius_mm + 1.0
        local, ras = _labels_near(volume, segmentation, sphere.centre, reach)
        if local is None:
            continue
        inside = np.linalg.norm(ras - sphere.centre, axis=-1) <= reach
        for label in np.unique(local[inside]):
            if label > 0:
                seeds[int(label)].append((sphere.centre, reach))
    return seeds, _post_feet(volume, segmentation, spheres, len(census.sizes))


def _labels_near(volume, segmentation, centre, reach):
    """The segmentation's labels in a box reaching ``reach`` mm round an RAS point, with their voxels' RAS."""
    box, ras = volume.voxels_within(centre - reach, centre + reach)
    if box is None:
        return None, None
    origin = segmentation.origin
    low = np.maximum(np.array([s.start for s in box]) - origin, 0)
    high = np.minimum(np.array([s.stop for s in box]) - origin, segmentation.labels.shape)
    if (high <= low).any():
        return None, None
    local = segmentation.labels[tuple(slice(a, b) for a, b in zip(low, high))]
    start = low + origin - np.array([s.start for s in box])
    return local, ras[tuple(slice(a, a + n) for a, n in zip(start, local.shape))]


#: Posts and a frame below the threshold are brighter than this (HU); air is darker.
DIM_BODY_HU = -650.0
#: ... and they lie within this (mm) of the spheres' box. However large the dim region reached from the spheres, it
#: leads on: soft tissue it takes in meets the bone over a wide area (``MAX_LINK_MM2``) and links nothing, and a
#: plastic plate can be larger than any size set for it (fresh wide seed 61019 at 62 HU of noise: a 119 HU plate of
#: 177 cm^3 holding an 8.7 mm bar that rests on a flat bone; with dim regions over 150 cm^3 taken for soft tissue,
#: the bar was not linked and 1,464 of the 4,748 IPC points were on it, exit 0).
DIM_BODY_REACH_MM = 40.0
#: A sphere's own object no larger than this (mm^3) is a sphere on its post, whose end the dim parts start at.
SPHERE_ON_POST_MM3 = 5_000.0
#: Dim parts meet an object over at most this area (mm^2, counted in cells): a post's foot, a bracket's end.
MAX_LINK_MM2 = 400.0
#: The dim parts are followed on a grid of about this (mm): the brightest voxel of each cell, so a thin post stays.
DIM_CELL_MM = 1.5


def _dim_links(volume, segmentation, spheres, sizes_all, holding=()):
    """[(label, point (3,) RAS)]: objects above the threshold that the spheres reach through dimmer parts of the
    reference body (posts or a frame between DIM_BODY_HU and the threshold, or plastic spheres): where they meet.
    ``holding``: the labels of the objects that hold a sphere (its own, or its bright post's under a dim sphere).

    Followed on a grid of DIM_CELL_MM cells, each as bright as its brightest voxel; cells next to an object above
    the threshold are left out, so that the blurred rim every bright object has in air (which is in the dim range
    too) does not lead from one object to the next; the dim parts meet an object where they come within two cells
    of it. Objects smaller than MIN_BONE_MM3 count as dim parts.
    """
    if not spheres:
        return []
    voxel_mm3 = float(np.prod(volume.spacing))
    own = {s.label for s in spheres if s.label > 0} | set(holding)
    own = [label for label in sorted(own) if sizes_all[label] * voxel_mm3 <= SPHERE_ON_POST_MM3]
    if not own and not any(_dim_next_to(volume, segmentation, sphere) for sphere in spheres):
        return []  # nothing dim leaves any sphere: no dim post, no plastic sphere
    centres = np.array([sphere.centre for sphere in spheres])
    origin, shape = segmentation.origin, np.array(segmentation.labels.shape)
    ijk = volume.ras_to_ijk_points(centres) - origin
    block = np.maximum(1, np.rint(DIM_CELL_MM / volume.spacing)).astype(int)
    reach = (DIM_BODY_REACH_MM + MARKER_DIAMETER_MM) / volume.spacing
    low = np.maximum(np.floor(ijk.min(axis=0) - reach).astype(int), 0)
    high = np.minimum(np.ceil(ijk.max(axis=0) + reach).astype(int) + 1, shape)
    high = low + (high - low) // block * block
    if (high <= low).any():
        return []
    box = tuple(slice(a, b) for a, b in zip(low, high))
    brightest = block_max(segmentation.smoothed[box], block)
    # Objects above the threshold; specks of noise smaller than an object (a dim frame's, with a noisy CT) are dim.
    is_object = np.zeros(int(segmentation.labels.max()) + 1, dtype=bool)
    is_object[list(segmentation.object_labels)] = True
    # Objects smaller than the smallest bone are dim parts too: the pieces the threshold breaks a frame about its HU
    # into (13028: a 215 HU ring under a 200 HU threshold in pieces of 0.3-0.7 cm^3, which kept the spheres' dim parts
    # from the bracket at its hub). They lead on, and none is linked: no bone is that small.
    is_object[sizes_all[: len(is_object)] * voxel_mm3 < MIN_BONE_MM3] = False
    bright = block_max(is_object[segmentation.labels[box]], block)
    dim = (brightest >= DIM_BODY_HU) & ~dilate_by_cube(bright)
    regions, _ = ndimage.label(dim)
    # The dim parts that start at a sphere's surface: cells within 2.5 mm beyond it.
    grid = np.stack(np.meshgrid(*[np.arange(n) for n in dim.shape], indexing="ij"), axis=-1)
    cells_ras = volume.ijk_to_ras_points((grid * block + (block - 1) / 2.0 + low + origin).reshape(-1, 3))
    start, posts = np.zeros(dim.size, dtype=bool), np.zeros(dim.size, dtype=bool)
    for sphere in spheres:
        distance = np.linalg.norm(cells_ras - sphere.centre, axis=1)
        start |= distance <= sphere.radius_mm + 2.5
        posts |= distance <= sphere.radius_mm + MAX_POST_MM
    start, posts = start.reshape(dim.shape), posts.reshape(dim.shape)
    # ... or at the end of a sphere's own bright object within a post's length of it (a bright post on a dim frame).
    # (Only a small object: a sphere on its post. When the sphere's object is large, bone and body are one object
    # already, and its cells would start the dim parts in the soft tissue round the bone.)
    if own:
        own_cells = block_max(np.isin(segmentation.labels[box], own), block)
        start |= dilate_by_cube(own_cells, 5) & posts  # two cells out, past the rim the bright cells leave out
    linked = np.unique(regions[start & dim])
    links = []
    for region in linked[linked > 0]:
        near = dilate(regions == region, iterations=2) & bright
        contacts = []
        for cell in np.argwhere(near):
            voxels = tuple(slice(a, a + n) for a, n in zip(low + cell * block, block))
            inside = np.argwhere(is_object[segmentation.labels[voxels]])
            label = int(segmentation.labels[voxels][tuple(inside[0])])
            contacts.append((label, inside[0] + low + cell * block + origin))
        for label in {label for label, _ in contacts}:
            points = [point for other, point in contacts if other == label]
            if len(points) * float(np.prod(volume.spacing[:2] * block[:2])) > MAX_LINK_MM2:
                continue  # met over a wide area: soft tissue round a bone, not a post's foot or a bracket's end
            links += [
                (label, point) for point in volume.ijk_to_ras_points(np.array(points[:: max(1, len(points) // 20)]))
            ]
    return links


#: A post is at most this long (mm from the sphere's surface to the frame).
MAX_POST_MM = 30.0


def _post_feet(volume, segmentation, spheres, labels_count):
    """[(label, foot (3,) RAS)]: the objects the spheres' posts stand on (``labels_count``: the segmentation's
    highest label and one). An NDI tool's markers lie in a plane and its posts stand square to it, so from each
    sphere the way along the plane's normal (either side) that stays brighter than DIM_BODY_HU is its post, whatever
    its brightness (below, above or about the threshold), and the first object on it other than the sphere's own and
    the specks of a post about the threshold is its frame."""
    if len(spheres) < 3:
        return []
    centres = np.array([sphere.centre for sphere in spheres])
    normal = np.linalg.svd(centres - centres.mean(axis=0))[2][2]
    objects = np.zeros(labels_count, dtype=bool)
    objects[list(segmentation.object_labels)] = True
    step = 0.5 * float(volume.spacing.min())
    feet = []
    for sphere in spheres:
        own = _labels_at(volume, segmentation, sphere.centre[None])[0]
        distances = np.arange(sphere.radius_mm + 0.5, sphere.radius_mm + MAX_POST_MM, step)
        for side in (1.0, -1.0):
            points = sphere.centre + side * distances[:, None] * normal
            ijk = volume.ras_to_ijk_points(points) - segmentation.origin
            values = ndimage.map_coordinates(segmentation.smoothed, ijk.T, order=1, mode="constant", cval=-1000.0)
            labels = _labels_at(volume, segmentation, points)
            air = np.flatnonzero(values < DIM_BODY_HU)
            hit = np.flatnonzero(objects[labels] & (labels != own))
            if len(hit) and (len(air) == 0 or hit[0] < air[0]):
                feet.append((int(labels[hit[0]]), points[hit[0]]))
    return feet


def _dim_next_to(volume, segmentation, sphere):
    """True when dim voxels (DIM_BODY_HU up to the threshold) lie 1 to 2.5 mm beyond a sphere's surface, clear of the
    blurred rim of anything above the threshold: a dim post or frame leaves it (or the sphere itself is dim)."""
    reach = sphere.radius_mm + 2.5
    local, ras = _labels_near(volume, segmentation, sphere.centre, reach)
    if local is None:
        return False
    box, _ = volume.voxels_within(sphere.centre - reach, sphere.centre + reach)
    low = np.maximum(np.array([s.start for s in box]) - segmentation.origin, 0)
    values = segmentation.smoothed[tuple(slice(a, a + n) for a, n in zip(low, local.shape))]
    steps = int(np.ceil(DIM_CELL_MM / float(volume.spacing.min())))
    clear = ~dilate(local > 0, iterations=steps) if (local > 0).any() else np.ones(local.shape, bool)
    distance = np.linalg.norm(ras - sphere.centre, axis=-1)
    shell = (distance >= sphere.radius_mm + 1.0) & (distance <= reach)
    return bool((shell & clear & (values >= DIM_BODY_HU)).any())


def _labels_at(volume, segmentation, points):
    """(N,) the segmentation's labels at the voxels nearest RAS points (N, 3); 0 outside its box."""
    index = np.rint(volume.ras_to_ijk_points(points)).astype(int) - segmentation.origin
    inside = np.all((index >= 0) & (index < segmentation.labels.shape), axis=1)
    labels = np.zeros(len(points), dtype=int)
    labels[inside] = segmentation.labels[tuple(index[inside].T)]
    return labels


@dataclass(frozen=True)
class _Cut:
    """The bone's part of an object that also holds the body: ``bone`` cells on the object's grid, the margin (mm)
    round the body within which IPC points are left out, and the opening (mm) that cut it; ``followed``: the cells
    the body's material took from what the opening kept (``_follow_body_material``: their edge is the plateau's,
    not the opening's, and needs a narrower margin, ``ct_segmentation.FOLLOWED_MARGIN_MM``), or None."""

    bone: np.ndarray
    margin_mm: float
    opening_mm: float
    followed: np.ndarray = None


class _ObjectShape:
    """One object on a grid of about CELL_MM: filled mask, depth (mm from its surface), block mean and max HU."""

    def __init__(self, volume, segmentation, label, region, max_cells=MAX_CELLS):
        spacing = volume.spacing
        self.block = _grid_block(region, spacing, max_cells)
        self.cell = spacing * self.block
        self.spacing = spacing
        self.label = label
        self.segmentation = segmentation
        self._ijk_to_ras = volume.ijk_to_ras
        shape = np.array(segmentation.labels.shape)
        pad = 2 * self.block
        low = np.array([max(s.start - p, 0) for s, p in zip(region, pad)])
        high = np.array([min(s.stop + p, n) for s, p, n in zip(region, pad, shape)])
        high = low + (high - low) // self.block * self.block  # whole blocks
        self.low, self.high = low, high
        box = tuple(slice(a, b) for a, b in zip(low, high))
        # A cell holds the object when any of its voxels does: a thin cortex stays closed round the marrow.
        self.mask = block_max(segmentation.labels[box] == label, self.block)
        self.mean_hu = block_means(segmentation.smoothed[box], self.block)
        self.max_hu = block_max(segmentation.smoothed[box], self.block)
        # Cells on the CT's sides: where the field of view cuts the object, its rim there is its inside.
        first = segmentation.origin + low
        cells = np.array(self.mask.shape)
        self.at_edge = np.zeros(self.mask.shape, dtype=bool)
        open_sides = []  # the sides of the grid's box that are not on the CT's (the object ends inside the box)
        for axis in range(3):
            index = first[axis] + np.arange(cells[axis]) * self.block[axis]
            edge = (index <= self.block[axis]) | (index + 2 * self.block[axis] >= volume.voxels.shape[axis])
            self.at_edge |= edge.reshape([-1 if a == axis else 1 for a in range(3)])
            open_sides += [(axis, side) for side, on_edge in ((0, edge[0]), (-1, edge[-1])) if not on_edge]
        # A round field of view's padding (a value below any air's, in whole cells) is the CT's side too.
        self._open_sides, self._padding = open_sides, self.max_hu < PADDING_HU
        self.filled = _filled(self.mask, open_sides, self._padding)
        self.depth = ndimage.distance_transform_edt(self.filled, sampling=self.cell)
        self.filled_mm3 = float(self.filled.sum() * np.prod(self.cell))
        self._solid_parts = None
        self._whole_measures = None
        self._refill = None

    def verdict(self, spheres, filled=None, depth=None):
        """ObjectVerdict of the object (or of a part: its ``filled`` cells and their ``depth``). The whole object's
        measures are taken once (the recognition asks for its verdict after each cut that finds nothing)."""
        if filled is None:
            volume, half, cortex, air_inside = self._whole()
            filled = self.filled
        else:
            volume, half, cortex, air_inside = self._measures(filled, self.depth if depth is None else depth)
        verdict = "reference body" if spheres else _by_measures(volume, half, cortex)
        thin = verdict == "too small or thin" and volume >= MIN_BONE_MM3
        if (verdict == "bone without a cortex" or thin) and filled is self.filled:
            refilled = self._refilled()
            if refilled is not None:
                return self.verdict(spheres, *refilled)
        return ObjectVerdict(self.label, volume, half, cortex, spheres, verdict, air_inside)

    def _whole(self):
        """``_measures`` of the whole object, taken once."""
        if self._whole_measures is None:
            self._whole_measures = self._measures(self.filled, self.depth)
        return self._whole_measures

    def _has_a_cortex(self):
        """True when the whole object, as it is, is bone with a cortex by its measures (``verdict``, without a
        round field of view's padding taken for the CT's side: a body's object is seldom walled by it)."""
        volume, half, cortex, _ = self._whole()
        return _by_measures(volume, half, cortex) == "bone"

    def _measures(self, filled, depth):
        """(volume mm^3, half its largest thickness mm, cortex contrast HU or None, whether its inside is air) of the
        ``filled`` cells at ``depth`` (mm)."""
        volume = float(filled.sum() * np.prod(self.cell))
        half = float(depth.max()) if filled.any() else 0.0
        inside = self._inside(filled, depth)
        air_inside = bool(inside.any() and np.median(self.mean_hu[inside]) < ENCLOSED_AIR_HU)
        return volume, half, self._cortex(filled, depth), air_inside

    def _walled_by_the_padding(self):
        """(filled, depth) of the object with the cells between it and a round field of view's padding (a cell from
        both) taken for the CT's side too, when that gives it a cortex; None otherwise. Where the field of view cuts a
        bone along its length, a layer of such cells (part padding, part CT) joined its marrow to the tissue round
        it: unfilled, its deepest cells were the cortex and a steel pin (+2,487 HU), its rim read -1,850 HU on them,
        and the tibia was refused as a solid frame (12013); a flat bone's inside below the threshold, opened so, left
        its two tables too thin for a bone (28060: 18.5 cm^3 under 4 mm thick, refused with 56 cm^3 of bone in view).
        Only a verdict of no cortex, or too thin for an object large enough, is looked at again: as the CT's side
        everywhere, those cells closed pockets that the cut off the reference body and the bone's surface depend on
        (16002, 16090)."""
        if not self._padding.any():
            return None
        padding = self._padding | (dilate(self._padding) & dilate(self.mask))
        filled = _filled(self.mask, self._open_sides, padding)
        if filled.sum() <= self.filled.sum():
            return None
        walled = self._with_a_cortex(filled)
        return None if walled is None else walled[:2]

    def _refilled(self):
        """(filled, depth) of the object filled otherwise, when its fill gives it no cortex and another does: with
        more of a round field of view's padding for the CT's side, plugged, or with none of it (the first that gives
        a cortex); None otherwise. Measured once (the recognition asks for the whole object's verdict again)."""
        if self._refill is None:
            self._refill = (self._walled_by_the_padding() or self._plugged() or self._not_walled_by_the_padding(),)
        return self._refill[0]

    def _not_walled_by_the_padding(self):
        """(filled, depth) of the object filled with a round field of view's padding not taken for the CT's side, when
        that gives it a cortex; None otherwise. Where a bone solid at the threshold (its cancellous inside above it)
        runs along the field of view's edge, the tissue between the two is enclosed by the bone and the padding:
        filled, it was the object's inside and most of its rim, and the bone was refused as a solid frame (fresh
        family seed 48024: a flat bone 12.6 mm thick of 1,165 HU round 434 HU, under 6.7 mm of tissue, the fill 27 mm
        thick with its rim 190 HU dimmer than its inside; filled without the padding, +498 HU)."""
        if not self._padding.any():
            return None
        filled = _filled(self.mask, self._open_sides)
        if filled.sum() >= self.filled.sum():
            return None
        unwalled = self._with_a_cortex(filled)
        if unwalled is None:
            return None
        logger.info(
            "object %d filled without the padding: a cortex round its inside (+%.0f HU)", self.label, unwalled[2]
        )
        return unwalled[:2]

    def _plugged(self):
        """(filled, depth) of the object with the inside it encloses once the holes in its walls up to twice
        ``plugs.PLUG_MM`` wide are plugged (``plugs``), or up to twice WIDE_PLUG_MM, when that gives it a cortex; None
        otherwise. A bracket below the threshold inserted into a bone makes such a hole, and through it the marrow is
        one region with the outside: a flat bone cut by the CT's box on all sides but one, its inside below the
        threshold, was two tables of cortex to the fill, its rim no brighter than its inside, and it was refused as a
        solid frame (family seed 40232 with wide brackets: a 116 HU bracket 9.3 mm wide into a 1.1 mm cortex round a
        163 HU inside; 115 cm^3 of bone in view). Only when a side of the box is off the CT's edge to tell the outside
        by."""
        if not self._open_sides:
            return None
        between = None  # the bone's sides, read once, where a plug first encloses something
        for reach_mm in (PLUG_MM, WIDE_PLUG_MM):
            plug = closed_holes(self.mask, self.cell, reach_mm)
            if not plug.any():
                continue
            enclosed = reaching_no_side(~self.mask & ~plug & ~self._padding, self._open_sides) & ~self.filled
            if not enclosed.any():
                continue
            if between is None:
                open_sides = set(self._open_sides)
                on_edge = [((axis, 0) not in open_sides, (axis, -1) not in open_sides) for axis in range(3)]
                between = between_sides(self.mask | self._padding, on_edge, None) >= 2
            inside = inside_pieces(enclosed, between, np.prod(self.cell))
            plugged = self._with_a_cortex(self.filled | inside) if inside.any() else None
            if plugged is not None:
                logger.info(
                    "object %d encloses %.1f cm^3 once the holes in its walls up to %.0f mm are plugged: a cortex "
                    "round it (+%.0f HU)",
                    self.label,
                    inside.sum() * np.prod(self.cell) / 1000.0,
                    2.0 * reach_mm,
                    plugged[2],
                )
                return plugged[:2]
        return None

    def _with_a_cortex(self, filled):
        """(filled, depth, cortex contrast HU) of the object filled so (``filled`` cells), when that gives it a cortex
        (CORTEX_CONTRAST_HU); None otherwise."""
        depth = self._depth_of(filled)
        cortex = self._cortex(filled, depth)
        return (filled, depth, cortex) if cortex is not None and cortex >= CORTEX_CONTRAST_HU else None

    def _cortex(self, filled, depth, round_the_inside=False):
        """The rim's brightness (HU, 75th percentile of the cells' maxima) less the inside's (median of the deepest
        cells' means), None when it has no rim or no inside; ``round_the_inside``: only the rim that surrounds the
        inside (within its depth and a cell), as a cortex surrounds its marrow, not that of a brighter part joined to
        a dimmer thick one (a metal frame on a bracket)."""
        rim = self._rim(filled, depth)
        if (rim & ~self.at_edge).any():
            rim &= ~self.at_edge
        inside = self._inside(filled, depth)
        if round_the_inside and inside.any():
            rim &= self._within(inside, float(depth.max()) + float(self.cell.max()))
        if not rim.any() or not inside.any():
            return None
        return float(self._rim_hu(rim) - np.median(self.mean_hu[inside]))

    def _rim(self, filled, depth):
        """The ``filled`` cells within RIM_MM (and a cell) of their surface (``depth``, mm): where a cortex is."""
        return filled & (depth <= max(self.cell.max(), RIM_MM))

    def _rim_hu(self, rim):
        """The brightness (HU) of a rim's cells: the 75th percentile of their maxima."""
        return float(np.percentile(self.max_hu[rim], 75))

    def _inside(self, filled, depth):
        """The deepest of the ``filled`` cells (at least 60 % of the largest ``depth``, and a cell and a half)."""
        return filled & (depth >= max(0.6 * float(depth.max()), self.cell.max() * 1.5))

    def solid_parts(self):
        """[(point (3,) RAS, reach mm)]: where the object is a solid part (a frame, a bracket: no cortex) joined to a
        part with a cortex, [] when it is not: the body's seeds when no marker sphere says where it is (its spheres
        out of the field of view or sunk into its frame). Measured once (``_find_solid_parts``)."""
        if self._solid_parts is None:
            self._solid_parts = self._find_solid_parts()
        return self._solid_parts

    def _find_solid_parts(self):
        """``solid_parts``.

        Opened by balls of shrinking radius, the object falls apart at its necks; the first opening that leaves at
        least two cores of MIN_CORE_MM3, one of them (opened back) with a cortex and another with a rim no brighter
        than its inside (by less than SOLID_CONTRAST_HU), names the solid ones, by some of their cells. Voxels
        coarser than SOLID_MAX_VOXEL_MM blur a cortex into the bone's inside: no part is told solid in them.
        """
        cell_mm3 = float(np.prod(self.cell))
        if self.filled_mm3 < 2.0 * MIN_BONE_MM3 or self.spacing.max() > SOLID_MAX_VOXEL_MM + 1e-6:
            return []
        for opening in [r for r in OPENING_RADII_MM[::-1] if r <= self.depth.max()]:
            cores, count = ndimage.label(self.depth >= opening)
            if count < 2:
                continue
            sizes = np.bincount(cores.ravel(), minlength=count + 1)
            sizes[0] = 0
            big = [core for core in np.argsort(-sizes)[:MAX_CORES] if sizes[core] * cell_mm3 >= MIN_CORE_MM3]
            if len(big) < 2:
                continue
            contrasts = in_parallel(*[partial(self._core_contrast, cores == core, opening) for core in big])
            solid = [core for core, c in zip(big, contrasts) if is_solid(c)]
            if not solid or not any(c is not None and c >= CORTEX_CONTRAST_HU for c in contrasts):
                continue
            cells = self._cell_centres_ras()
            seeds = []
            for core in solid:
                points = cells[cores == core]
                seeds += [(point, opening) for point in points[:: max(1, len(points) // SOLID_SEEDS)]]
            logger.info(
                "%d solid part(s) without a cortex joined to the bone: taken for the reference body", len(solid)
            )
            return seeds
        return []

    def _core_contrast(self, core, opening, among=None):
        """The cortex contrast (``_cortex``) of the part of ``among`` (cells; the filled object by default) that a
        ``core`` opened by ``opening`` mm holds."""
        part = (self.filled if among is None else among) & self._within(core, opening)
        return self._cortex(part, self._depth_of(part))

    def _takes_bone(self, body, bone, no_bone_on_body, no_more_bone_on_body):
        """True when the guards of ``cut_off_body`` refuse a cut: with ``no_bone_on_body``, the ``body`` (cells) holds a
        bone-like piece (``_bone_like``); with ``no_more_bone_on_body``, such a piece larger than the ``bone`` kept."""
        if not (no_bone_on_body or (no_more_bone_on_body and body.sum() > bone.sum())):
            return False
        return self._bone_like(body, bone)

    def _stub_margin_mm(self, opening_mm):
        """The margin (mm) round the body's side within which IPC points are left out: the stub an opening of
        ``opening_mm`` leaves on the bone (up to its radius high) and the coarse cells, a cell or two more."""
        return opening_mm + 2.0 * float(self.cell.max()) + 1.0

    def _bone_like(self, cells, bone):
        """True when ``cells`` hold a piece of at least MIN_BONE_MM3 with a cortex (CORTEX_CONTRAST_HU) round its
        inside, and that inside is darker by as much than the rim of the ``bone`` (cells): a piece of the same bone
        holds its marrow, not a frame brighter than the bone's cortex where a dimmer bracket meets it (family seed
        25023: a 2,032 HU plate on an 812 HU bracket resting on a tibia of 1,118 HU, the junction's inside 1,374 HU,
        +623 HU under the plate's rim; the tibia was refused)."""
        if cells.sum() * np.prod(self.cell) < MIN_BONE_MM3:
            return False
        depth = self._depth_of(cells)
        contrast = self._cortex(cells, depth, round_the_inside=True)
        if contrast is None or contrast < CORTEX_CONTRAST_HU:
            return False
        inside = np.median(self.mean_hu[self._inside(cells, depth)])
        return inside <= self._rim_hu(self._rim(bone, self._depth_of(bone))) - CORTEX_CONTRAST_HU

    def cut_off_body(self, seeds, no_bone_on_body=False, no_more_bone_on_body=False):
        """(ObjectVerdict, _Cut or None): the bone's part of an object that is the reference body's at ``seeds``
        ([(point, reach mm)]: its spheres, the feet of its posts), cut off where a rod leaves it (see the module
        docstring), or the verdict 'reference body' when no bone is in it (or, with ``no_bone_on_body``, when the
        body's side would hold a piece with a cortex; with ``no_more_bone_on_body``, such a piece larger than the
        bone kept). With no ``seeds`` (no sphere anywhere), only the solid parts the bone's core grows are the
        body's; without one, there is no cut (None). On an object thick enough, a cut with the wide openings too
        (WIDE_OPENING_RADII_MM) that leaves no bone-like piece on the body's side is taken instead when what the first
        kept and it does not is solid (a bracket wider than the first's largest opening), or when the first found no
        cut, and only when its openings went on below the wide ones: one that stops at a wide opening found the
        bone's thickest part alone before the body's seeds (family seed 17044, a 9.9 mm bracket inserted into a 29 mm
        long bone, its first cut with the solid parts' seeds none: the wide one stopped at 9 mm, 77.6 % of the bone
        covered, where the cut without the solid parts' seeds covers 84.5 %)."""
        guard = {"no_bone_on_body": no_bone_on_body, "no_more_bone_on_body": no_more_bone_on_body}
        start = in_parallel(partial(self._apart_from_seeds, seeds), self._cell_centres_ras)
        cuts = [partial(self._cut_off_body, seeds, *start, OPENING_RADII_MM, **guard)]
        if self.depth.max() >= WIDE_OPENING_RADII_MM[0]:  # the wide cut too, at once (it reads what the first does)
            wide = OPENING_RADII_MM + WIDE_OPENING_RADII_MM
            cuts.append(partial(self._cut_off_body, seeds, *start, wide, no_bone_on_body=True))
        (verdict, cut), *wide_cuts = in_parallel(*cuts)
        if wide_cuts:
            wide_verdict, wide_cut = wide_cuts[0]
            # A wide cut that stops at a wide opening found only the bone's thickest part before the body's seeds.
            down = wide_cut is not None and wide_cut.opening_mm < WIDE_OPENING_RADII_MM[0]
            if down and (cut is None or self._kept_a_solid_part(cut.bone & ~wide_cut.bone)):
                verdict, cut = wide_verdict, wide_cut
        if cut is not None:
            logger.info("reference body cut off the bone by an opening of %.1f mm", cut.opening_mm)
            followed = self._follow_body_material(cut)
            if followed is not cut:
                verdict, cut = self.verdict(0, followed.bone, self._depth_of(followed.bone)), followed
        return verdict, cut

    def followed_from_seeds(self, seeds, no_bone_on_body=False, no_more_bone_on_body=False):
        """(ObjectVerdict, _Cut) or None: the body followed by its material (``_follow_body_material``) from the
        ``seeds`` that hold it for sure [(point (3,) RAS, reach mm): spheres, posts' feet, dim parts; not the solid
        parts, which may be the bone's own], in an object that looks like bone as a whole (a cortex) where no opening
        parts the body from the bone (``cut_off_body`` found no cut): a bracket nearly as thick as the bone, held by
        the body's seeds at its far end (family seed 107 with a thick bar: a 12.1 mm square bar of 1,053 HU resting on
        a long bone 13.9 mm thick, its 186 HU frame below the threshold and linked to the bar by the dim parts: no
        cut, and 6,800 of 14,548 IPC points on the bar). The cells within the seeds' reach and a cell are the body's
        side; what the following leaves must be bone (``_bone_cut_off``), and with the guards (``cut_off_body``) the
        body it takes no bone-like piece."""
        if not seeds or not self._has_a_cortex():
            return None
        near_seeds = self._within_reach_of(seeds, float(self.cell.max()))
        beyond = self.filled & ~near_seeds
        if not (near_seeds & self.filled).any():
            return None
        # What lies beyond the seeds' reach has a cortex too, by the object's own depth (no distance transform): a
        # body's object alone (a frame, its posts) has none there, and is not followed (the bench CT's: 0.13 s).
        contrast = self._cortex(beyond, np.where(beyond, self.depth, 0.0))
        if contrast is None or contrast < CORTEX_CONTRAST_HU:
            return None
        start = _Cut(beyond, self._stub_margin_mm(0.0), 0.0)
        followed = self._follow_body_material(start)
        if followed is start:
            return None
        verdict = self.verdict(0, followed.bone, self._depth_of(followed.bone))
        if not _keeps_the_rim(verdict, contrast):
            return None
        if self._takes_bone(self.filled & ~followed.bone, followed.bone, no_bone_on_body, no_more_bone_on_body):
            return None
        logger.info("reference body followed by its material from its seeds, no opening parting it from the bone")
        return verdict, followed

    def without_solid_parts(self, seeds):
        """(ObjectVerdict, _Cut) or None: the object without its solid parts (``seeds``: ``solid_parts``, cells of
        their cores, each reaching as far as the opening that found it), where no opening parts them from the bone
        and no plateau is followed: a bracket resting on a bone nearly as thick, the bone's core within the part's
        reach at every opening (fresh wide seed 62035 at 62 HU of noise: a 14 mm rod of 527 HU on a long bone 17.6 mm
        thick whose cortex is 773 HU; the object refused with 24.9 cm^3 of bone in view). The largest piece left must
        be bone with a cortex, and what goes with the parts no bone-like piece (``_takes_bone``). Only parts found at
        an opening of WHOLE_PART_MIN_OPENING_MM or more: a bracket, not the thin pieces of a frame."""
        if min(reach for _, reach in seeds) < WHOLE_PART_MIN_OPENING_MM:
            return None
        bone = largest_piece(self.filled & ~self._within_reach_of(seeds, float(self.cell.max())))
        if not bone.any():
            return None
        verdict = self.verdict(0, bone, self._depth_of(bone))
        if verdict.verdict != "bone" or self._takes_bone(self.filled & ~bone, bone, True, False):
            return None
        logger.info("the solid parts taken off the bone whole: no opening parts them")
        return verdict, _Cut(bone, self._stub_margin_mm(0.0), 0.0)

    def _follow_body_material(self, cut):
        """The ``cut`` with the body followed by its material into the bone it kept (``body_material``; a bracket
        nearly as thick as the bone, which no opening parts from it), or the cut itself when no plateau is the body's.
        Where the cell means are noisier than NOISY_HU (``means_noise_hu``, among the cells at least MATERIAL_DEEP_MM
        deep), a step that takes nothing by them reads the levels again from the means averaged over the object's cells
        3 x 3 x 3 (``averaged_means``; held-out wide draw 3009: 72 HU, a 20.3 mm bar of 956 HU inserted into a long bone
        22.2 mm thick, no level read on either side of the cut; the checks of a plateau still read the cells' own
        means), and a plateau is then taken only apart from the level of the bone's inside far from the body, which
        must be read (wide seed 40204: with the cut keeping none of the bone far from the body, a flat bone's 370 HU
        inside, read so, was taken for the body's). At every step, not the first only: wide seed 40278, 51 HU of
        noise, a 7.3 mm bar of 1,479 HU resting on a flat bone 8.2 mm thick, its 196 HU frame followed first; the bar's
        cells of 1.5 mm held no 3 x 3 x 3 neighbourhood flat enough for a level, and 2,407 IPC points were the bar's."""
        around = self._around_cut(cut.bone)
        readings = [(self.mean_hu, False)]
        if means_noise_hu(self.mean_hu, self.filled & (self.depth >= MATERIAL_DEEP_MM)) > NOISY_HU:
            readings.append((averaged_means(self.mean_hu, self.filled), True))
        return self._follow_levels(cut, readings, around)

    def _around_cut(self, bone):
        """What every reading of the levels takes from the ``bone`` a cut kept (cells), whatever the means it reads:
        (the cells of the body's side at least MATERIAL_DEEP_MM deep within MATERIAL_LEVELS_MM of the bone, the
        distances (mm) of all cells to the body's side, exact to MATERIAL_FAR_MM, and the inside of the bone farther
        than MATERIAL_FAR_MM from it)."""
        # The first plateau goes on across the cut: the body's side holds its level too, where it has levels to read
        # (the bone's own cortex, thick enough to be a plateau where a bracket rests on it, does not: 40317, a 783 HU
        # cortex under a 295 HU bar; 40231's body, its frame apart, leaves the cut 67 cells too thin to read).
        near_cut = self._distance_to(bone, MATERIAL_LEVELS_MM) <= MATERIAL_LEVELS_MM
        across_cells = self.filled & ~bone & (self.depth >= MATERIAL_DEEP_MM) & near_cut
        # A later plateau may be the bone's inside, bared where a bracket inserted into it was taken (40170: an ilium's
        # 265 HU inside taken after its 958 HU bracket, 60 % of its coverage lost): not at the level of the inside of
        # the bone far from the body.
        to_body = self._distance_to(self.filled & ~bone, MATERIAL_FAR_MM)  # the first step's too (a longer reach)
        far = bone & (to_body > MATERIAL_FAR_MM)
        far_inside = self._inside(far, self._depth_of(far)) if far.any() else far
        return across_cells, to_body, far_inside

    def _follow_levels(self, cut, readings, around):
        """``_follow_body_material`` with the levels and plateaus read, at each step, from the first of ``readings``
        [((I, J, K) HU: the cell means or their average, apart_from_inside)] that takes a plateau, ``around`` the cut
        (``_around_cut``); with ``apart_from_inside``, every plateau's level must be apart from the bone's inside level
        (at every step, not the later ones only), and that level read. The first plateau's level is on the body's side
        of the cut too (where that side has a level to read); a plateau taken moves the cut, and the next one (a
        frame's, then its bracket's) is read from there. A plateau that leaves no cortex is taken only if the next one
        leaves bone with a cortex (given back otherwise): a metal bracket inserted into the bone hides its cortex until
        it is taken too (fresh wide seed 53044: a star frame of 609 HU, 9.3 mm thick, and its 2,303 HU bracket inserted
        into a fibula in air; the frame left the fibula with the bracket in it, no cortex, and nothing was followed:
        12,840 of 19,071 IPC points were the frame's and the bracket's, exit 0)."""
        bone = cut.bone
        across_cells, to_body, far_inside = around
        read = []  # (levels_hu, apart_from_inside, the levels across the cut, the inside's level)
        for levels_hu, apart_from_inside in readings:
            inside_level = float(np.median(levels_hu[far_inside])) if far_inside.any() else None
            if not (apart_from_inside and inside_level is None):
                read.append((levels_hu, apart_from_inside, levels_among(levels_hu, across_cells), inside_level))
        confirmed = bone  # the bone after the last plateau that left bone
        for step in range(MATERIAL_STEPS):
            if step > 0:
                to_body = self._distance_to(self.filled & ~bone, MATERIAL_LEVELS_MM)
            deep = bone & (self.depth >= MATERIAL_DEEP_MM)
            seeds = deep & (to_body <= MATERIAL_TOUCH_MM)
            near = deep & (to_body <= MATERIAL_LEVELS_MM)  # where the levels are read
            taken = None
            for levels_hu, apart_from_inside, across, inside_level in read:
                taken = self._plateau_taken(
                    bone,
                    levels_hu,
                    step,
                    (seeds, near, to_body),
                    across,
                    far_inside,
                    inside_level,
                    apart_from_inside,
                    may_await=bone is confirmed and step + 1 < MATERIAL_STEPS,
                )
                if taken is not None:
                    break
            if taken is None:
                break
            part, level, awaiting = taken
            # With the blur round the plateau (its edge, between its level and what it meets), a cell or two; but
            # what the rest of the bone encloses (a bracket's end inserted into it) stays with the bone: it adds no
            # surface, and taken away it would cost the bone's surface round it.
            part = dilate(part, MATERIAL_BLUR_CELLS, within=bone)
            part &= ~_filled(bone & ~part, self._open_sides, self._padding)
            if not part.any():
                break
            logger.info(
                "the body followed into the bone kept by its material of %.0f HU: %.0f mm^3%s",
                level,
                part.sum() * np.prod(self.cell),
                " (if a plateau after it leaves bone with a cortex)" if awaiting else "",
            )
            bone = bone & ~part
            if not awaiting:
                confirmed = bone
        if bone is not confirmed:
            logger.info("the last plateau followed given back: no plateau after it leaves bone")
            bone = confirmed
        if bone is cut.bone:
            return cut
        bone = self._without_pieces_split_off(bone, cut.bone & ~bone)
        return _Cut(bone, cut.margin_mm, cut.opening_mm, followed=cut.bone & ~bone)

    def _without_pieces_split_off(self, bone, taken):
        """The ``bone`` (cells) a following left, without the pieces smaller than MIN_BONE_MM3 that the plateaus
        ``taken`` (cells) split off its largest and that reach farther than ROD_TO_MM from it: the body's parts of
        another material, which its plateaus held to the bone (fresh wide seed 49044: a 2,433 HU plate and its 14.6 mm
        bar followed, their 1,267 HU posts left, 65 IPC points 29-55 mm from the bone), or the blurred edge of a bar
        under 62 HU of noise (wide seed 40279 drawn as the held-out 3009: pieces 3-14 mm from the bone, 5 IPC points).
        The specks of blur a plateau leaves wholly next to the bone stay (their own surface is none of the IPC's, but
        as the body's they took the bone's surface within ``ct_segmentation.FOLLOWED_MARGIN_MM`` of them: thick bar
        104, 576 IPC points, 97.7 -> 93.1 % of the bone covered). Such a piece may still hang on the bone by the
        blurred rim a plateau leaves round it (fresh wide seed 53010: a 1,642 HU bar followed under 73 HU of noise, the
        3.4 mm arm of its 1,009 HU star frame joined to the fibula by the bar's rim, 122 IPC points 30-60 mm off the
        bone): the pieces are looked for again with the bone opened by a cube SPLIT_OPENING_CELLS wide, where that
        keeps at least half of it in its largest piece, and those with no cortex go with their rim (up to two cells the
        opening took). A piece with a cortex is the bone's: a fibula's far side, past a bracket inserted through it
        (wide seed 40260: 1.2 cm^3, 95.0 -> 82.8 % of the bone covered when it went)."""
        far, _ = self._far_small_pieces(bone, taken, 1)
        bone = bone & ~far
        opened = open_by_cube(bone, SPLIT_OPENING_CELLS)
        far, largest = self._far_small_pieces(opened, taken, SPLIT_OPENING_CELLS // 2 + 1)
        if not far.any() or largest.sum() < 0.5 * bone.sum():
            return bone
        pieces, count = ndimage.label(far)
        for piece in range(1, count + 1):
            cells = pieces == piece
            contrast = self._cortex(cells, self._depth_of(cells))
            if contrast is not None and contrast >= CORTEX_CONTRAST_HU:
                far &= ~cells  # a piece of the bone the plateau split (wide seed 40260: a fibula's far side, +992 HU)
        return bone & ~dilate(far, 2, within=bone & ~opened & ~dilate(largest, 2))

    def _far_small_pieces(self, bone, taken, touching_cells):
        """(the pieces of ``bone`` (cells) smaller than MIN_BONE_MM3 within ``touching_cells`` of ``taken`` that reach
        farther than ROD_TO_MM from its largest piece, the largest piece): ``_without_pieces_split_off``."""
        nothing = np.zeros(bone.shape, dtype=bool)
        pieces, count = ndimage.label(bone)
        if count < 2:
            return nothing, bone
        sizes = np.bincount(pieces.ravel(), minlength=count + 1)
        sizes[0] = 0
        largest = sizes.argmax()
        small = sizes * np.prod(self.cell) < MIN_BONE_MM3
        small[largest] = False
        split_off = np.unique(pieces[dilate(taken, touching_cells) & (pieces > 0)])
        split_off = split_off[small[split_off]]
        if not split_off.size:
            return nothing, pieces == largest
        beyond = np.unique(pieces[(self._distance_to(pieces == largest, ROD_TO_MM) > ROD_TO_MM) & (pieces > 0)])
        return np.isin(pieces, np.intersect1d(split_off, beyond)), pieces == largest

    def _plateau_taken(
        self, bone, levels_hu, step, where, across, far_inside, inside_level, apart_from_inside, may_await=False
    ):
        """(part, level HU, awaiting) of the first plateau of ``bone`` (cells) at a level read from ``levels_hu`` that
        is the body's (``_is_the_bodys``) and leaves bone (``_leaves_bone``), or None; ``where``: (seeds, near: cells,
        to_body: mm) of this ``step``. With ``may_await``, and none leaving bone, the first that leaves an object as
        thick as bone with no cortex (``awaiting`` True): the next plateau may be what hides its cortex
        (``_follow_levels``). After the first step, where no level is read, the levels are read among the near cells'
        own neighbours: from a plateau of the body taken, a thin bar whose every neighbourhood meets its blur (wide seed
        40278: a 7.3 mm bar on cells of 1.5 mm, after its frame). Not at the first: with no level across the cut, 505 HU
        read so in a flat bone (between its cortex and its inside) took 156 cm^3 of it (wide seed 40185)."""
        seeds, near, to_body = where
        awaiting = None
        levels = levels_among(levels_hu, near)
        if not levels and step > 0:
            levels = levels_among(levels_hu, near, neighbours_among_cells=True)
        for level in levels:
            if step == 0 and across and all(abs(level - other) > BAND_HU for other in across):
                continue
            at_inside = inside_level is not None and abs(level - inside_level) <= BAND_HU
            if (step > 0 or apart_from_inside) and at_inside:
                continue
            part = plateau_from_nearest(levels_hu, bone, level, seeds, near, to_body, float(self.cell.max()))
            rest = bone & ~part
            if not self._is_the_bodys(part, rest, level, far_inside, inside_level):
                continue
            leaves_bone, left = self._leaves_bone(part, rest)
            if leaves_bone:
                return part, level, False
            if may_await and awaiting is None and left.verdict == "bone without a cortex":
                awaiting = (part, level, True)
        return awaiting

    def _is_the_bodys(self, part, rest, level, far_inside, inside_level):
        """True when a plateau ``part`` (cells, at ``level`` HU) of the bone a cut kept is the body's: at least
        MIN_CORE_MM3, solid (``_plateau_is_solid``: a rim no brighter than its inside, whatever the noise), smaller
        than the ``rest`` of the bone, not the cortex round it (a shell: its cavities more than MATERIAL_CAVITY_SHARE
        of it, at the level of the bone's inside, ``inside_level`` HU, or None where it was not read), and not the
        bone's inside: neither most of ``far_inside`` (cells: the inside of the bone far from the body; more than
        MATERIAL_FAR_INSIDE_SHARE of them) nor a plateau the rest surrounds (less than MATERIAL_OPEN_FRACTION of the
        ring MATERIAL_RING_MM round the part outside the rest) with a ring no darker than the part. Whether the rest
        is bone still is ``_leaves_bone``'s to say."""
        if part.sum() * np.prod(self.cell) < MIN_CORE_MM3 or part.sum() >= rest.sum():
            return False
        if (part & far_inside).sum() > MATERIAL_FAR_INSIDE_SHARE * far_inside.sum():
            return False  # a bracket as bright as the bone's inside, inserted into it: one plateau with it
        if not self._plateau_is_solid(part):
            return False
        cavity = _filled(part, self._open_sides, self._padding) & ~part
        if cavity.sum() > MATERIAL_CAVITY_SHARE * part.sum():
            # A shell round a cavity: a thick cortex round the bone's inside. A cavity of another level is the body's
            # own (3009: a bar's end, 955 HU, inserted into its plate, the bone's inside -63 HU).
            if inside_level is None or abs(np.median(self.mean_hu[cavity]) - inside_level) <= BAND_HU:
                return False
        ring = self._within(part, MATERIAL_RING_MM) & ~part
        in_rest = ring & rest
        enclosed = in_rest.sum() > (1.0 - MATERIAL_OPEN_FRACTION) * ring.sum()
        return not (enclosed and np.median(self.mean_hu[in_rest]) >= level)

    def _leaves_bone(self, part, rest):
        """(whether the ``rest`` a plateau ``part`` (cells) of the body leaves is bone still: a cortex, or the dimmer
        rim the bone had, ``_keeps_the_rim``; the rest's ObjectVerdict)."""
        left = self.verdict(0, rest, self._depth_of(rest))
        if left.verdict == "bone":
            return True, left
        if not _bone_cut_off(left):
            return False, left
        # A rim dimmer than a cortex, but one the bone kept had already (a flat bone whose inside is nearly as bright
        # as its cortex: fresh wide seed 49030, +96 HU with the 8.6 mm bar of 1,317 HU inserted into it and without).
        kept = self.verdict(0, part | rest, self._depth_of(part | rest))
        return _bone_cut_off(kept) and _keeps_the_rim(left, kept.cortex_hu), left

    def _plateau_is_solid(self, part):
        """``is_solid`` for a plateau ``part`` (cells), its rim contrast less what the noise alone lifts a cell's
        maximum above its mean in the part's inside (median, HU): the rim reads maxima, the inside means, and under
        heavy noise a uniform part's rim reads brighter than its inside (wide seed 41011 with 62 HU of noise: a
        2,057 HU bar +76-81 HU, a cortex to ``is_solid``, and 10,712 IPC points on the body)."""
        depth = self._depth_of(part)
        contrast = self._cortex(part, depth)
        if contrast is None:
            return False
        inside = self._inside(part, depth)
        return is_solid(contrast - float(np.median(self.max_hu[inside] - self.mean_hu[inside])))

    def _kept_a_solid_part(self, cells):
        """True when ``cells`` (what one cut kept with the bone and another did not) make a solid part of at least
        MIN_CORE_MM3: a rim brighter than its inside by less than WIDE_SOLID_CONTRAST_HU."""
        if cells.sum() * np.prod(self.cell) < MIN_CORE_MM3:
            return False
        return is_solid(self._cortex(cells, self._depth_of(cells)), WIDE_SOLID_CONTRAST_HU)

    def _apart_from_seeds(self, seeds):
        """What every cut of the object at ``seeds`` starts from: the cells within the seeds' reach (booleans), the
        rest of the object (booleans), and the rest's depth (mm, its distance transform)."""
        near_sphere = self._within_reach_of(seeds)
        rest = self.filled & ~near_sphere
        return near_sphere, rest, ndimage.distance_transform_edt(rest, sampling=self.cell)

    def _cut_off_body(
        self, seeds, apart_from_seeds, cells, openings, no_bone_on_body=False, no_more_bone_on_body=False
    ):
        """``cut_off_body`` with the opening radii ``openings`` (mm, smallest first), from ``_apart_from_seeds`` and
        the cells' centres (``_cell_centres_ras``). It writes none of them, nor the object's arrays."""
        centres = np.array([point for point, _ in seeds]).reshape(-1, 3)
        reaches = np.array([reach for _, reach in seeds]) + float(self.cell.max())
        near_sphere, rest, depth = apart_from_seeds
        # The bone's core: at the largest opening that leaves a part far from the body big enough to be a bone. A
        # bracket fixed into a bone is thinner than the bone there, so this opening has cut it.
        found = None
        for opening in [r for r in openings[::-1] if r <= depth.max()]:
            cores, count = ndimage.label(depth >= opening)
            sizes = np.bincount(cores.ravel(), minlength=count + 1)
            sizes[0] = 0
            for core in np.argsort(-sizes)[: min(3, count)]:
                if sizes[core] * np.prod(self.cell) < MIN_CORE_MM3:
                    break  # the opening of a core this small is no bone
                part = cores == core
                if _reaches(cells[part], centres, reaches + opening):
                    continue
                opened = rest & self._within(part, opening)
                # A thin bone's core, opened back, holds little of it (the smaller openings grow it): a quarter of
                # the smallest bone will do, unless the part is solid (a frame's far corner, not bone).
                if opened.sum() * np.prod(self.cell) < MIN_BONE_MM3 / 4.0:
                    continue
                contrast = self._cortex(opened, self._depth_of(opened))
                if not is_solid(contrast):
                    found = (opening, part, opened, contrast)
                    break
            if found:
                break
        if found is None:
            return self.verdict(len(seeds)), None
        # Smaller openings keep more of the bone (its thinner parts), until its core reaches the body. A rod its
        # core grows out of the bone kept so far is the bracket: it is set apart (with the opening's reach round
        # it), and the descent goes on without it, so a thin bone the bracket is fixed into is kept too.
        kept, core_kept, bone, own_contrast = found
        bone_going_on = _bone_going_on(own_contrast)
        apart = np.zeros(rest.shape, dtype=bool)
        margin = 0.0
        for opening in [r for r in openings[::-1] if r < kept]:
            part = self._core_through(depth >= opening, core_kept, apart)
            away = self._distance_to(bone, ROD_TO_MM)  # from the bone kept so far: the rods' band, the far parts
            rods = self._rods(part, bone, away, rest & ~apart, near_sphere, opening, bone_going_on)
            if rods.any():
                apart |= self._within(rods, opening + self.cell.max())
                margin = max(margin, min(opening, ROD_MARGIN_MAX_MM))
                part = self._core_through(part, core_kept, apart)
            solid = self._solid_parts_grown(part, away, rest, opening, MIN_CORE_MM3 if seeds else MIN_GROWN_SOLID_MM3)
            if solid.any():
                apart |= self._within(solid, opening + self.cell.max())
                part = self._core_through(part, core_kept, apart)
            if not part.any() or _reaches(cells[part], centres, reaches + opening):
                break
            kept, core_kept = opening, part
            bone = rest & ~apart & self._within(part, opening)
        bone = self._with_thin_bits(bone, rest & ~apart, near_sphere | apart)
        if not seeds and not apart.any():
            return self.verdict(0), None  # nothing is the body's
        verdict = self.verdict(0, bone, self._depth_of(bone))
        if not _bone_cut_off(verdict):
            return self.verdict(len(seeds)), None
        if self._takes_bone(rest & ~bone, bone, no_bone_on_body, no_more_bone_on_body):
            # What would be the body is bone too: the dim parts met the bone (a dim bracket's end in it), or a seed
            # tied by the tool's distances lay in it, and the cut went through the bone.
            return self.verdict(len(seeds)), None
        return verdict, _Cut(bone, self._stub_margin_mm(max(margin, kept)), kept)

    def _solid_parts_grown(self, core, away, rest, opening, min_mm3=MIN_CORE_MM3):
        """The cells of the bone's ``core`` (at ``opening`` mm) that make solid parts farther than ROD_TO_MM from the
        bone kept so far (``away``: the cells' distances to it, mm, exact up to ROD_TO_MM): pieces of at least
        ``min_mm3`` whose rim, opened back within ``rest``, is no brighter than their inside (``is_solid``). They are
        the body, which the seeds did not reach: a ring frame's far side between the seeds of its solid
        junctions, its core grown in through the bracket (18037: 13 cm^3 of a 2,480 HU ring kept with the bone).
        Over 200 CTs, such far pieces of the body were solid (rim -337 to +43 HU on the inside) and those of bone
        were not (+228 to +1,489 HU). Voxels coarser than SOLID_MAX_VOXEL_MM, and openings under
        SOLID_GROWN_MIN_OPENING_MM, tell no solid part."""
        solid = np.zeros(core.shape, dtype=bool)
        if self.spacing.max() > SOLID_MAX_VOXEL_MM + 1e-6 or opening < SOLID_GROWN_MIN_OPENING_MM:
            return solid
        pieces, count = ndimage.label(core & (away > ROD_TO_MM))
        if count == 0:
            return solid
        sizes = np.bincount(pieces.ravel(), minlength=count + 1)
        sizes[0] = 0
        for piece in np.argsort(-sizes)[:MAX_CORES]:
            if sizes[piece] * np.prod(self.cell) < min_mm3:
                break
            if is_solid(self._core_contrast(pieces == piece, opening, rest)):
                solid |= pieces == piece
        if solid.any():
            logger.info("the bone's core grew a solid part at an opening of %.1f mm: the body's, set apart", opening)
        return solid

    @staticmethod
    def _core_through(cores, core_kept, apart):
        """The connected piece of ``cores`` (cells, outside ``apart``) that holds most of ``core_kept``."""
        labels, _ = ndimage.label(cores & ~apart)
        overlap = np.bincount(labels[core_kept], minlength=2)
        overlap[0] = 0
        return labels == overlap.argmax() if overlap.max() > 0 else np.zeros(cores.shape, dtype=bool)

    def _rods(self, core, bone, away, rest, body, opening, bone_going_on=CORTEX_CONTRAST_HU):
        """The cells of ``core`` that leave ``bone`` (cells; ``away`` their distances to it, mm, exact up to
        ROD_TO_MM) as the bracket: pieces crossing the band ROD_FROM_MM to ROD_TO_MM from the bone that lead
        through ``rest`` outside the bone to the ``body`` (cells by the spheres and the posts' feet) and are solid (a
        thin shaft of the bone itself that the bracket is fixed into has its marrow cavity where its core runs; a flat
        bone whose cancellous core is above the threshold, its cortex)."""
        pieces, count = ndimage.label(core & (away > ROD_FROM_MM) & (away <= ROD_TO_MM))
        rods = np.zeros(core.shape, dtype=bool)
        if count == 0:
            return rods
        outside_bone, _ = ndimage.label(rest & ~bone)
        to_body = np.unique(outside_bone[dilate(body) & (outside_bone > 0)])
        cavity = self.filled & ~self.mask & (away > ROD_FROM_MM)  # outside the bone kept (its own marrow is in it)
        for piece in range(1, count + 1):
            cells = pieces == piece
            if away[cells].max() < ROD_TO_MM - self.cell.max():
                continue
            if not np.isin(outside_bone[cells], to_body).any():
                continue
            to_piece = self._distance_to(cells, opening + self.cell.max())
            around = to_piece <= opening + self.cell.max()
            # A shaft's marrow is where its core runs: a cavity beside the piece (soft tissue a slice encloses
            # between a bracket and what it meets) is no marrow of the piece's. Over 600 family CTs, the 20 pieces of
            # bone met here had 2-203 of their cavity's cells within 1 mm of their core; the cavities beside 6 of the 7
            # brackets' lay 2.4-5.5 mm from them (23012: 3.6 mm, its whole bracket kept with the bone).
            if self._marrow(cavity & (to_piece <= self.cell.max()), around):
                continue
            # No cavity, but a cortex round a dimmer inside above the threshold (a flat bone's cancellous core): the
            # bone going on, not a rod.
            beside = rest & ~bone & around
            contrast = self._cortex(beside, self._depth_of(beside))
            if contrast is None or contrast < bone_going_on:
                rods |= cells
        return rods

    def _marrow(self, cavity, around):
        """True when the ``cavity`` cells (filled, below the threshold) are marrow: two or more, two of them sharing
        a face, darker than the object's cells ``around`` them by a cortex's contrast (CORTEX_CONTRAST_HU, the cells'
        means), not the holes that noise leaves in a rod about the threshold (33028: a 229 HU bracket under 61 HU of
        noise, its holes 48 HU darker than it; 14163's 34 HU, 31007's 36 HU), a cell each and apart (23065: a 333 HU
        bracket under 71 HU of noise, three such holes 161 HU darker, 117 IPC points on it). Over 214 family CTs,
        the other cavities met next to a bone's core were 195-1,147 HU darker (12059: a piece of 2 cells, 1,003 HU;
        13031: 59 cells, 165 HU). Without the object's cells round them, they are taken for marrow."""
        if cavity.sum() < 2:
            return False
        pieces, _ = ndimage.label(cavity)  # face neighbours
        if np.bincount(pieces.ravel())[1:].max() < 2:
            return False
        rim = around & self.mask
        if not rim.any():
            return True
        darker = np.median(self.mean_hu[rim]) - np.median(self.mean_hu[cavity])
        return darker >= CORTEX_CONTRAST_HU

    def _distance_to(self, cells, reach_mm):
        """Distances (mm) of every cell to the nearest of ``cells``, exact up to ``reach_mm`` and inf beyond: the
        transform runs on the box of ``cells`` widened by the reach only (a core or rod is a small part of the
        grid)."""
        distance = np.full(cells.shape, np.inf)
        boxes = ndimage.find_objects(cells.view(np.uint8) if cells.dtype == bool else cells.astype(np.uint8))
        if not boxes or boxes[0] is None:
            return distance
        pad = np.ceil(reach_mm / self.cell).astype(int) + 1
        box = tuple(slice(max(s.start - p, 0), min(s.stop + p, n)) for s, p, n in zip(boxes[0], pad, cells.shape))
        distance[box] = ndimage.distance_transform_edt(~cells[box], sampling=self.cell)
        return distance

    def _depth_of(self, cells):
        """Depths (mm) of ``cells`` under their own surface (0 outside them): the transform runs on their box only."""
        depth = np.zeros(cells.shape)
        boxes = ndimage.find_objects(cells.view(np.uint8))
        if boxes and boxes[0] is not None:
            box = tuple(slice(max(s.start - 1, 0), min(s.stop + 1, n)) for s, n in zip(boxes[0], cells.shape))
            depth[box] = ndimage.distance_transform_edt(cells[box], sampling=self.cell)
        return depth

    def _within(self, cells, reach_mm):
        """The cells within ``reach_mm`` of any of ``cells`` (a dilation by a ball, in mm on the anisotropic grid)."""
        return self._distance_to(cells, reach_mm) <= reach_mm

    def _with_thin_bits(self, opened, rest, near_sphere):
        """The opened bone with the thin parts of ``rest`` that hang off it and do not lead to a sphere."""
        thin, count = ndimage.label(rest & ~opened)
        if count == 0:
            return opened
        touching_bone = np.unique(thin[dilate(opened) & (thin > 0)])
        leading_to_body = np.unique(thin[dilate(near_sphere) & (thin > 0)])
        keep = np.setdiff1d(touching_bone, leading_to_body)
        return opened | np.isin(thin, keep)

    def body_in_box(self, cut):
        """Booleans over the segmentation's box: the object's voxels on the body's side of the cut (the cells of
        the object not in the bone's part, and the half-empty cells along their surface)."""
        return self.cells_in_box(dilate(self.filled & ~cut.bone) & ~cut.bone)

    def cells_in_box(self, cells):
        """Booleans over the segmentation's box: the object's voxels in ``cells`` (booleans over the grid)."""
        voxels = unblock(cells, self.block, tuple(self.high - self.low))
        box = tuple(slice(a, b) for a, b in zip(self.low, self.high))
        whole = np.zeros(self.segmentation.labels.shape, dtype=bool)
        whole[box] = (self.segmentation.labels[box] == self.label) & voxels
        return whole

    def _within_reach_of(self, seeds, more_mm=0.0):
        """The cells within the reach of any of ``seeds`` [(point (3,) RAS, reach mm)], and ``more_mm``."""
        near = np.zeros(self.filled.shape, dtype=bool)
        for centre, reach in seeds:
            near |= self._ball(centre, reach + more_mm)
        return near

    def _ball(self, centre, reach_mm):
        """The cells whose centres lie within ``reach_mm`` of ``centre`` (3,) RAS: summed per axis, as the grid's
        axes are orthogonal (a distance-preserving frame in mm), without the (I, J, K, 3) offsets."""
        ras_to_ijk = np.linalg.inv(self._ijk_to_ras)
        ijk = ras_to_ijk[:3, :3] @ centre + ras_to_ijk[:3, 3]
        at = (ijk - self.segmentation.origin - self.low + 0.5) / self.block - 0.5  # in cells
        squared = [((np.arange(n) - a) * c) ** 2 for n, a, c in zip(self.mask.shape, at, self.cell)]
        return squared[0][:, None, None] + squared[1][None, :, None] + squared[2][None, None, :] <= reach_mm**2

    def _cell_centres_ras(self):
        """(I, J, K, 3) RAS mm: the centre of each cell of the object's grid."""
        grid = np.stack(np.meshgrid(*[np.arange(n) for n in self.mask.shape], indexing="ij"), axis=-1)
        ijk = self.segmentation.origin + self.low + (grid + 0.5) * self.block - 0.5
        return self._volume_ijk_to_ras(ijk)

    def _volume_ijk_to_ras(self, ijk):
        matrix = self._ijk_to_ras
        return ijk @ matrix[:3, :3].T + matrix[:3, 3]


def _grid_block(region, spacing, max_cells):
    """(3,) voxels per cell along each axis of the grid an object in the box ``region`` (3 slices) is measured on:
    cells of about CELL_MM, coarser for a large object so that its grid has about ``max_cells`` cells at most."""
    extent_mm = np.array([s.stop - s.start for s in region]) * spacing
    cell_mm = max(CELL_MM, float(np.prod(extent_mm) / max_cells) ** (1.0 / 3.0))
    return np.maximum(1, np.floor(cell_mm / spacing + 1e-6)).astype(int)


def _weighed(voxels, voxel_mm3):
    """True for an object of ``voxels`` voxels (of ``voxel_mm3``) large enough to be measured as a bone: filled, it
    may reach MIN_BONE_MM3."""
    return voxels * voxel_mm3 >= MIN_BONE_MM3 / 4.0


def finer_grids_possible(volume, segmentation):
    """True when an object large enough to be looked at as bone was measured on a grid coarser than FINE_MAX_CELLS
    would make it: only then is a second recognition on the finer grids worth its time."""
    slices, sizes = boxes_and_sizes(segmentation.labels)
    voxel_mm3 = float(np.prod(volume.spacing))
    return any(
        (
            _grid_block(slices[label - 1], volume.spacing, MAX_CELLS)
            > _grid_block(slices[label - 1], volume.spacing, FINE_MAX_CELLS)
        ).any()
        for label in segmentation.object_labels
        if slices[label - 1] is not None and _weighed(sizes[label], voxel_mm3)
    )


def _filled(mask, open_sides=(), padding=None):
    """The mask with its cavities filled: the holes enclosed in a slice along any axis, and the holes in 3-D that
    reach none of ``open_sides`` ([(axis, 0 or -1)]: the box's sides off the CT's edge) other than through
    ``padding`` (cells outside a round field of view): where the field of view cuts a bone, its marrow reaches the
    CT's side, enclosed in no slice when the bone lies oblique to the grid, but it is the bone's inside."""
    filled = mask.copy()
    for axis in range(3):
        in_slice = np.zeros((3, 3, 3), dtype=bool)
        in_slice[tuple(1 if a == axis else slice(None) for a in range(3))] = True
        holes, _ = ndimage.label(~mask, structure=in_slice)  # every slice labelled apart, in one call
        edge = [np.take(holes, side, axis=a) for a in range(3) if a != axis for side in (0, -1)]
        filled |= (holes > 0) & ~np.isin(holes, np.unique(np.concatenate([e.ravel() for e in edge])))
    if 0 < len(open_sides) < 6:  # (none: it fills the field of view; all: the slices found its enclosed holes)
        filled |= reaching_no_side(~filled if padding is None else ~filled & ~padding, open_sides)
    return filled


def is_solid(contrast, limit_hu=SOLID_CONTRAST_HU):
    """True when a rim ``contrast`` (HU, ``_ObjectShape._cortex``; None without a rim or an inside) is a solid
    part's: a rim no brighter than its inside (by less than ``limit_hu``, SOLID_CONTRAST_HU by default)."""
    return contrast is not None and contrast < limit_hu


def _bone_going_on(contrast):
    """The rim contrast (HU) a piece growing out of the bone must have to be the bone going on, not a rod: a cortex
    (CORTEX_CONTRAST_HU), or, on a bone whose own rim is dimmer (``contrast``: a flat bone whose cancellous inside is
    nearly as bright as its cortex, +110 HU, family seed 15036), four fifths of its own, and more than a solid part's
    (SOLID_CONTRAST_HU)."""
    if contrast is None:
        return CORTEX_CONTRAST_HU
    return min(CORTEX_CONTRAST_HU, max(SOLID_CONTRAST_HU, 0.8 * contrast))


def _by_measures(volume_mm3, half_thickness_mm, cortex_hu):
    """What an object without spheres is by its measures (``_ObjectShape.verdict``): 'too small or thin' (under
    MIN_BONE_MM3 or MIN_HALF_THICKNESS_MM), 'bone' (a cortex of CORTEX_CONTRAST_HU or more), or 'bone without a
    cortex'."""
    if volume_mm3 < MIN_BONE_MM3 or half_thickness_mm < MIN_HALF_THICKNESS_MM:
        return "too small or thin"
    if cortex_hu is not None and cortex_hu >= CORTEX_CONTRAST_HU:
        return "bone"
    return "bone without a cortex"


def _bone_cut_off(verdict):
    """True when the part a cut took off the body is bone: it has a cortex, or a rim brighter than its inside by more
    than a solid part's (SOLID_CONTRAST_HU: a flat bone whose cancellous inside is nearly as bright as its cortex,
    +89 HU, family seed 15065); such a part is taken for the bone only when no object has a cortex, with a warning."""
    if verdict.verdict == "bone":
        return True
    return verdict.verdict == "bone without a cortex" and (verdict.cortex_hu or 0.0) >= SOLID_CONTRAST_HU


def _keeps_the_rim(left, kept_hu):
    """True when what a following left of the bone (``left``, an ObjectVerdict) is bone with a cortex, or has a rim
    dimmer than a cortex but more than a solid part's (``_bone_cut_off``) with KEPT_RIM_SHARE of the rim contrast (HU)
    of what it was taken from, ``kept_hu``. Wide seed 40131: followed from its spheres, the frame taken left a 13.6 mm
    bar of 612 HU with a little of the bone, +78 HU, where what was followed had a cortex; taken for the bone, 8,939 of
    11,216 IPC points were the bar's, exit 0."""
    if left.verdict == "bone":
        return True
    return _bone_cut_off(left) and left.cortex_hu >= KEPT_RIM_SHARE * kept_hu


def _may_hold_a_body(shape, seeds):
    """True when the recognition will ask for the object's solid parts: it holds the body's ``seeds`` and is large
    enough for a bone besides, or it holds none and looks like bone."""
    if seeds:
        return shape.filled_mm3 >= 2.0 * MIN_BONE_MM3
    return shape.verdict(0).verdict.startswith("bone")


def _reaches(points, centres, distances):
    """True when any of ``points`` (N, 3) lies within ``distances`` (K,) of any of ``centres`` (K, 3)."""
    for centre, distance in zip(centres, distances):
        if (np.linalg.norm(points - centre, axis=1) <= distance).any():
            return True
    return False


def _nothing_like_bone(verdicts, threshold_hu):
    found = "; ".join(f"object {i + 1}: {v.verdict} ({v.describe()})" for i, v in enumerate(verdicts)) or "nothing"
    return (
        f"no object in the CT's field of view is plausibly bone at the threshold of {threshold_hu:.0f} HU (found "
        f"{found}); a bone is at least {MIN_BONE_MM3 / 1000:.1f} cm^3, {2 * MIN_HALF_THICKNESS_MM:.0f} mm thick and "
        "holds no marker sphere: check that the bone is in the field of view and that the threshold is below its "
        "cortex (--threshold auto)"
    )
