"""Random reference-body CTs: a family of CT images of a bone with an NDI reference body, drawn over the range a
user can meet, each with its ground truth (issue 27).

The CTs that defeated the old detector were made by other software, so the family varies what the image side must
not depend on, the way the image is formed included:

* **the reference body**: one of the shipped 4-marker NDI tools in any orientation; marker spheres (11.5 mm) from
  plastic (100 HU) to metal (clipped at 3071 HU); posts 0-25 mm long (0: the sphere sits on the frame) and
  1.5-8 mm thick; a frame of rods from a hub (star), a ring of rods with a bar across, or a plate, 3-12 mm thick;
  posts and frame of any HU from 100 to 3071, brighter or dimmer than the spheres; now and then a sphere with a
  cap missing (Fig. 4a's defect);
* **a bracket** rod from the frame's hub to the bone, 4-12 mm thick (thinner than the bone it is fixed into) and of
  any HU: inserted into the bone (as the paper fixes its rigid body in the porcine ilium), resting on it, ending
  short of it, or absent; with ``wide_bracket_overrides(seed)``, a round rod or a square bar 8-20 mm across (up to
  0.9 of the bone's half-thickness), inserted or resting; with ``thick_bar_overrides(seed)``, a square bar 9-14 mm
  across and brighter than the cortex, resting on a long bone 12-18 mm thick;
* **the bone**: an analytic long bone (a tube of cortex round marrow or cancellous bone, with or without its
  rounded end in view), an analytic flat bone (two cortical tables round cancellous bone) or a shipped bone mesh
  (tibia, fibula, ilium); cortex 700-2000 HU; bare in air or in 3-25 mm of soft tissue; the field of view may
  hold only a short piece of it, less than the reference body;
* **clutter**: small bright blobs, a wire, a steel pin through the bone, a spare marker sphere lying apart;
* **the grid**: voxels of 0.3-1.0 mm (in-plane and across slices drawn apart), axis-aligned or turned;
* **image formation** (``solid_painting``): partial volume as a linear ramp, by supersampling, or none; a Gaussian
  point spread of 0.4-0.9 voxel in-plane and across slices (the cortex kept 2.5 of its sigmas thick); noise of
  2-80 HU, white or spatially correlated; streaks from every metal object (``ct_painting.add_metal_streaks``,
  amplitude scaled 0.3-1.5); a field of view whose box or reconstruction cylinder (padded with -1024, -2048 or
  -3024 HU) may cut spheres.

``make_family_ct(seed)`` draws and renders one CT: (CTVolume, FamilyTruth). The truth holds the true sphere centres
in the tool's order with the state of each (``STATES``), the bone and the reference body as solids (the exact
distance of any point to their surfaces), and every choice of the draw (``settings``, flat, by name). Any choice
can be forced by name (``overrides``) without changing the others. ``profile='quick'`` keeps a CT to about 1.5
million voxels (the unit tests), ``'full'`` to about 4 million (the benchmark), by coarsening the drawn spacing
(never beyond 1 mm) when the field of view needs more; the spacing used is in the settings.
"""

from dataclasses import dataclass

import numpy as np

from ..core.transforms import make_transform, rotation_about_axis
from ..image.volume_io import CTVolume
from ..io.ndi_tools import MARKER_DIAMETER_MM, tool_marker_geometry
from .ct_painting import LPS_DIRECTION, STREAK_HU, add_metal_streaks
from .solid_painting import PARTIAL_VOLUME_MODELS, mesh_signed_on_grid, paint, scan
from .solids import Ball, Capsule, CutBall, MeshSolid, Slab, Union

#: Largest CT (voxels) per profile.
PROFILES = {"quick": 1_500_000, "full": 4_000_000}
#: The shipped NDI tools with 4 markers (8700248 is collinear).
FAMILY_TOOLS = ("8700339", "8700449", "8700340")
FAMILY_MESHES = ("right-tibia", "right-fibula", "right-ilium")
#: About half the thinnest part of each mesh where a bracket may go (mm): the shaft's radius, half the wing.
MESH_HALF_THICKNESS_MM = {"right-tibia": 9.0, "right-fibula": 5.0, "right-ilium": 4.0}
#: A sphere is 'visible' when the field of view holds it and this much (mm) around it (its blurred edge), ...
VISIBLE_MARGIN_MM = 2.0
#: ... and at least this fraction of its surface is bare (not sunk into the frame or covered by its post).
MIN_EXPOSED = 0.8
STATES = ("visible", "edge", "cut", "damaged", "hidden")
#: Bracket shapes: a round rod (every seed's draw) or a square bar (``wide_bracket_overrides``).
BRACKET_SHAPES = ("round", "square")
#: A bracket's radius is at most this share of the bone's half-thickness: the seed's own draw, and with
#: ``wide_bracket_overrides`` (the stream WIDE_STREAM apart from the CT's).
BRACKET_CAP = 0.6
WIDE_BRACKET_CAP = 0.9
WIDE_STREAM = 27
#: ``thick_bar_overrides``'s stream, apart from the CT's and the wide brackets'.
THICK_BAR_STREAM = 777
#: The reference body stands at least this far (mm) off the bone's soft tissue (its bracket goes through it).
BODY_CLEARANCE_MM = 5.0
#: The cortex is at least this many point-spread sigmas thick (see ``make_family_ct``).
CORTEX_SIGMAS = 2.5
AIR_HU = -1000.0
METAL_FROM_HU = 2500.0
HU_RANGE = (100.0, 3071.0)


@dataclass(frozen=True)
class FieldOfView:
    """The CT's field of view: its box of voxel centres and, optionally, the reconstruction cylinder (axis along
    the grid's k axis through index (i, j) = ``cylinder_centre_ij``, radius ``cylinder_radius_mm``)."""

    ijk_to_ras: np.ndarray
    shape: tuple
    cylinder_centre_ij: tuple = None
    cylinder_radius_mm: float = None

    def clearance(self, points):
        """(N,) distance (mm) from each RAS point to the edge of the field of view, negative outside."""
        ijk = (np.asarray(points, float) - self.ijk_to_ras[:3, 3]) @ np.linalg.inv(self.ijk_to_ras[:3, :3]).T
        spacing = np.linalg.norm(self.ijk_to_ras[:3, :3], axis=0)
        last = np.array(self.shape) - 1
        clearance = np.min(np.minimum(ijk, last - ijk) * spacing, axis=1)
        if self.cylinder_radius_mm is not None:
            radial = np.linalg.norm((ijk[:, :2] - self.cylinder_centre_ij) * spacing[:2], axis=1)
            clearance = np.minimum(clearance, self.cylinder_radius_mm - radial)
        return clearance

    def outside_cylinder(self):
        """(I, J) booleans: in-plane positions outside the reconstruction cylinder (None without one)."""
        if self.cylinder_radius_mm is None:
            return None
        spacing = np.linalg.norm(self.ijk_to_ras[:3, :3], axis=0)
        i, j = np.meshgrid(np.arange(self.shape[0]), np.arange(self.shape[1]), indexing="ij")
        centre = self.cylinder_centre_ij
        radial = np.hypot((i - centre[0]) * spacing[0], (j - centre[1]) * spacing[1])
        return radial > self.cylinder_radius_mm


@dataclass(frozen=True)
class FamilyTruth:
    """Ground truth of a family CT, RAS mm.

    ``marker_states`` per marker, one of ``STATES``: 'visible' (wholly in the field of view with
    ``VISIBLE_MARGIN_MM`` to spare, at least ``MIN_EXPOSED`` of its surface bare, undamaged), 'edge' (in it, with
    less to spare), 'cut' (by the field of view), 'damaged' (a cap missing), 'hidden' (sunk into the frame).
    """

    tool_id: str
    markers_reference: np.ndarray
    marker_centres: np.ndarray
    marker_radius_mm: float
    marker_states: tuple
    bone: object
    body: object
    bracket: object
    field_of_view: FieldOfView
    settings: dict

    @property
    def visible(self):
        """(K,) booleans: the spheres the image side must find to the target."""
        return np.array([state == "visible" for state in self.marker_states])

    @property
    def cut(self):
        return np.array([state == "cut" for state in self.marker_states])

    @property
    def bracket_joined(self):
        """True when the bracket touches the bone (inserted into it or resting on it)."""
        return self.settings["bracket"] in ("inserted", "resting")

    def bone_distance(self, points):
        """(N,) distance (mm) of RAS points to the true bone surface."""
        return np.abs(self.bone.signed_distance(np.asarray(points, float)))

    def body_distance(self, points):
        """(N,) signed distance (mm) of RAS points to the reference body with its bracket (negative inside)."""
        return self.body.signed_distance(np.asarray(points, float))

    def bone_in_view_mm3(self, volume, step_mm=1.0):
        """Volume (mm^3) of the bone inside the field of view (the box and, with one, the reconstruction cylinder),
        counted on a grid of cells about ``step_mm`` wide: what a refusal is judged by (a bone under
        ``bone_recognition.MIN_BONE_MM3`` in view is rightly refused)."""
        step = np.maximum(1, np.round(step_mm / volume.spacing)).astype(int)
        grid = np.stack(np.meshgrid(*[np.arange(0, n, s) for n, s in zip(volume.voxels.shape, step)], indexing="ij"))
        points = volume.ijk_to_ras_points(grid.reshape(3, -1).T)
        if isinstance(self.bone, MeshSolid):  # the stencil: a mesh's signed distance over a grid takes minutes
            whole = tuple(slice(0, n) for n in volume.voxels.shape)
            inside = self.bone.inside_on_grid(volume, whole)[tuple(slice(None, None, s) for s in step)].ravel()
        else:
            inside = self.bone.signed_distance(points) < 0.0
        inside &= self.field_of_view.clearance(points) > 0
        return float(inside.sum() * np.prod(step * volume.spacing))

    def bone_surface_points(self, volume, spacing_mm=1.0):
        """(N, 3) points on the true bone surface inside the field of view, about ``spacing_mm`` apart."""
        if isinstance(self.bone, MeshSolid):
            samples, _ = self.bone.surface_samples()
            samples = samples[self.field_of_view.clearance(samples) > 0]
            _, first = np.unique(np.floor(samples / spacing_mm).astype(np.int64), axis=0, return_index=True)
            return samples[first]
        step = np.maximum(1, np.round(spacing_mm / volume.spacing)).astype(int)
        grid = np.stack(np.meshgrid(*[np.arange(0, n, s) for n, s in zip(volume.voxels.shape, step)], indexing="ij"))
        points = volume.ijk_to_ras_points(grid.reshape(3, -1).T)
        near = points[np.abs(self.bone.signed_distance(points)) < 0.6 * spacing_mm]
        for _ in range(3):  # Newton steps onto the zero level along the numerical gradient
            signed = self.bone.signed_distance(near)
            gradient = np.stack([(self.bone.signed_distance(near + 0.05 * e) - signed) / 0.05 for e in np.eye(3)], 1)
            gradient /= np.maximum(np.linalg.norm(gradient, axis=1, keepdims=True), 1e-9)
            near = near - signed[:, None] * gradient
        return near[self.field_of_view.clearance(near) > 0]


def make_family_ct(seed, profile="quick", overrides=None, render=True):
    """Draw and render one reference-body CT (see the module docstring).

    Args:
        seed: the draw's seed.
        profile: 'quick' or 'full' (the largest CT, ``PROFILES``).
        overrides: {name: value} forcing choices of the draw (names as in the truth's ``settings``), e.g.
            ``{"bracket": "inserted", "sphere_hu": 800.0}``; the other choices stay as the seed draws them.
        render: False skips the painting (the CT is air): the draw and the truth only.

    Returns:
        (CTVolume, FamilyTruth).

    Raises:
        ValueError: an unknown profile or override name.
    """
    if profile not in PROFILES:
        raise ValueError(f"profile {profile!r}: use one of {', '.join(PROFILES)}")
    draw = _Draw(np.random.default_rng(seed), overrides)
    bone, anchor, normal, along, bone_layers = _draw_bone(draw)
    body = _draw_body(draw, anchor, normal, bone)
    volume, field_of_view = _draw_grid(draw, profile, body, anchor, normal, along, bone)
    image = _draw_image(draw, volume.spacing)
    # A cortex thinner than the point spread has no surface a level can find (its blurred peak falls below it):
    # the cortex is kept at least CORTEX_SIGMAS sigmas thick.
    cortex = max(-bone_layers[-1][0], CORTEX_SIGMAS * max(image["blur_in_plane_mm"], image["blur_across_mm"]))
    bone_layers[-1] = (-cortex, bone_layers[-1][1])
    draw.values["cortex_mm"] = cortex
    clutter = _draw_clutter(draw, volume, bone, anchor, along, normal, body)
    draw.check()
    settings = {"seed": int(seed), "profile": profile, **draw.values, "spacing_mm": volume.spacing.tolist()}
    settings["shape"] = list(volume.voxels.shape)
    states = _marker_states(body, field_of_view)
    truth = FamilyTruth(
        tool_id=draw.values["tool"],
        markers_reference=body["markers_reference"],
        marker_centres=body["centres"],
        marker_radius_mm=MARKER_DIAMETER_MM / 2.0,
        marker_states=states,
        bone=bone,
        body=Union(tuple(solid for solid, _ in body["parts"])),
        bracket=body["bracket"],
        field_of_view=field_of_view,
        settings=settings,
    )
    if not render:
        return CTVolume(voxels=volume.voxels.astype(np.int16), ijk_to_ras=volume.ijk_to_ras), truth
    signed = mesh_signed_on_grid(bone) if isinstance(bone, MeshSolid) else None
    paint(volume, bone, bone_layers, image["partial_volume"], signed_on_grid=signed)
    metal = []
    for solid, hu in body["parts"] + clutter:
        box, fraction = paint(volume, solid, [(0.0, hu)], image["partial_volume"])
        if box is not None and hu >= METAL_FROM_HU:
            metal.append((box, fraction))
    for box, fraction in metal:
        add_metal_streaks(volume, box, fraction, amplitude_hu=STREAK_HU * image["streak_scale"])
    voxels = scan(
        volume,
        (image["blur_in_plane_mm"], image["blur_across_mm"]),
        image["noise_hu"],
        draw.rng,
        image["correlation_voxels"] if image["noise"] == "correlated" else 0.0,
        field_of_view.outside_cylinder(),
        draw.values.get("padding_hu") or AIR_HU,
    )
    return CTVolume(voxels=voxels, ijk_to_ras=volume.ijk_to_ras), truth


class _Draw:
    """The named random choices of one CT: ``draw(name, value)`` returns the value drawn (already drawn, so that the
    stream of random numbers is the same whatever is overridden) or the override of that name; every choice is
    kept in ``values``."""

    def __init__(self, rng, overrides):
        self.rng = rng
        self.overrides = dict(overrides or {})
        self.values = {}

    def __call__(self, name, value):
        value = self.overrides.get(name, value)
        if isinstance(value, np.generic):
            value = value.item()
        self.values[name] = value
        return value

    def uniform(self, name, low, high):
        return self(name, float(self.rng.uniform(low, high)))

    def log_uniform(self, name, low, high):
        return self(name, float(np.exp(self.rng.uniform(np.log(low), np.log(high)))))

    def choice(self, name, options, p=None):
        return self(name, options[int(self.rng.choice(len(options), p=p))])

    def chance(self, name, probability):
        return self(name, bool(self.rng.random() < probability))

    def check(self):
        unknown = sorted(set(self.overrides) - set(self.values))
        if unknown:
            raise ValueError(f"overrides {', '.join(unknown)}: no such choice; use names from a truth's settings")


def _random_rotation(rng):
    q = rng.normal(size=4)
    w, x, y, z = q / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def _perpendicular(vector, rng):
    other = rng.normal(size=3)
    other -= (other @ vector) * vector
    return other / np.linalg.norm(other)


def _tilted(direction, max_deg, rng):
    return rotation_about_axis(_perpendicular(direction, rng), np.radians(rng.uniform(0.0, max_deg))) @ direction


def _draw_bone(draw):
    """The bone solid, the anchor (a point on its surface where the bracket goes), the outward normal there, the
    direction along the bone, and the layers to paint it with [(offset mm, HU)]."""
    rng = draw.rng
    kind = draw.choice("bone", ("long", "flat", "mesh"), p=[0.45, 0.3, 0.25])
    cortex_hu = draw.uniform("cortex_hu", 700.0, 2000.0)
    tissue = draw("tissue_mm", float(rng.uniform(3.0, 25.0)) if rng.random() < 0.6 else 0.0)
    tissue_hu = draw.uniform("tissue_hu", 0.0, 70.0)
    if kind == "long":
        axis = _tilted(np.array([0.0, 0.0, 1.0]), 90.0, rng)
        radius = draw.uniform("bone_radius_mm", 7.0, 16.0)
        cortex = min(draw.uniform("cortex_mm", 1.0, 4.0), 0.45 * radius)
        end_in_view = draw.chance("end_in_view", 0.3)
        length = rng.uniform(60.0, 160.0) if end_in_view else 400.0
        position = 0.5 * length - rng.uniform(15.0, 40.0) if end_in_view else 0.0
        normal = _perpendicular(axis, rng)
        anchor = position * axis + radius * normal
        bone = Capsule(-0.5 * length * axis, 0.5 * length * axis, radius)
        marrow = rng.random() >= 0.3
        interior = draw("interior_hu", float(rng.uniform(-100.0, 60.0) if marrow else rng.uniform(150.0, 500.0)))
        half_thickness, along = radius, axis
    elif kind == "flat":
        axes = _random_rotation(rng)
        half_thickness = 0.5 * draw.uniform("bone_thickness_mm", 8.0, 20.0)
        half = np.array([rng.uniform(40.0, 80.0), rng.uniform(40.0, 80.0), half_thickness])
        bone = Slab(np.zeros(3), axes, half, rounding=half_thickness)
        cortex = min(draw.uniform("cortex_mm", 0.8, 2.5), 0.35 * half_thickness)
        if draw.chance("into_crest", 0.35):  # the bracket into the rim, as the paper's into the ilium
            local, normal, along = np.array([half[0], rng.uniform(-20.0, 20.0), 0.0]), axes[:, 0], axes[:, 1]
        else:
            side = rng.choice([-1.0, 1.0])
            local = np.array([rng.uniform(-25.0, 25.0), rng.uniform(-25.0, 25.0), side * half_thickness])
            normal, along = side * axes[:, 2], axes[:, 0]
        anchor = axes @ local
        interior = draw.uniform("interior_hu", 150.0, 600.0)
    else:
        name = draw.choice("mesh", FAMILY_MESHES)
        bone = MeshSolid(name, make_transform(_random_rotation(rng)))
        samples, normals = bone.surface_samples()
        along = bone.pose[:3, 2]
        low, high = np.percentile(samples @ along, [20, 85])  # away from the joints' ends
        middle = np.flatnonzero((samples @ along > low) & (samples @ along < high))
        pick = int(rng.choice(middle))
        anchor, normal = samples[pick], normals[pick]
        flat = name == "right-ilium"
        cortex = draw.uniform("cortex_mm", *((0.8, 1.8) if flat else (1.2, 3.0)))
        interior = draw.uniform("interior_hu", *((150.0, 500.0) if flat else (-100.0, 60.0)))
        half_thickness = MESH_HALF_THICKNESS_MM[name]
    draw("bone_half_thickness_mm", float(half_thickness))
    layers = ([(tissue, tissue_hu)] if tissue > 0 else []) + [(0.0, cortex_hu), (-cortex, interior)]
    return bone, anchor, normal, along, layers


def _draw_body(draw, anchor, normal, bone):
    """The reference body and its bracket: {'parts': [(solid, HU)] to paint, bracket first, spheres last;
    'centres' (4, 3); 'markers_reference'; 'damaged', 'exposed' per sphere; 'bracket' solid or None; 'hub'}.

    The body stands clear of the bone and its soft tissue (``BODY_CLEARANCE_MM``): where the draw would put part of
    it inside them, the whole body moves out along the bracket.
    """
    rng = draw.rng
    tool = draw.choice("tool", FAMILY_TOOLS)
    markers_reference = tool_marker_geometry(tool)
    centred = markers_reference - markers_reference.mean(axis=0)
    radius = MARKER_DIAMETER_MM / 2.0
    direction = _tilted(normal, 30.0, rng)
    tissue = draw.values["tissue_mm"]
    length = draw.uniform("bracket_length_mm", 15.0, 60.0)
    x_axis = _tilted(direction, 40.0, rng)
    y_axis = rotation_about_axis(x_axis, rng.uniform(0.0, 2 * np.pi)) @ _perpendicular(x_axis, rng)
    rotation = np.column_stack((x_axis, y_axis, np.cross(x_axis, y_axis)))
    post_length = draw("post_length_mm", 0.0 if rng.random() < 0.15 else float(rng.uniform(3.0, 25.0)))
    sphere_hu = draw.log_uniform("sphere_hu", *HU_RANGE)
    post_hu = draw("post_hu", sphere_hu if rng.random() < 0.25 else _log_uniform(rng, *HU_RANGE))
    frame_hu = draw("frame_hu", post_hu if rng.random() < 0.4 else _log_uniform(rng, *HU_RANGE))
    bracket_hu = draw("bracket_hu", frame_hu if rng.random() < 0.4 else _log_uniform(rng, *HU_RANGE))
    post_radius = 0.5 * draw.uniform("post_diameter_mm", 1.5, 8.0)
    frame_kind = draw.choice("frame", ("star", "ring", "plate"), p=[0.45, 0.25, 0.3])
    frame_radius = 0.5 * draw.uniform("frame_thickness_mm", 3.0, 12.0)
    plate_margin = rng.uniform(2.0, 8.0)
    damaged = draw("damaged", [int(k + 1) for k in range(len(centred)) if rng.random() < 0.04])
    cap_depths = rng.uniform(2.0, 5.0, size=len(centred))
    state = draw.choice("bracket", ("inserted", "resting", "short", "none"), p=[0.35, 0.2, 0.25, 0.2])
    # A bracket fixed into a bone is thinner than the bone there (a thicker rod could not hold in it). The shape and
    # the cap are not drawn (every seed draws as before): ``wide_bracket_overrides`` sets them.
    shape = draw("bracket_shape", "round")
    if shape not in BRACKET_SHAPES:
        raise ValueError(f"bracket_shape {shape!r}: use one of {', '.join(BRACKET_SHAPES)}")
    thinner = draw("bracket_cap", BRACKET_CAP) * draw.values["bone_half_thickness_mm"]
    bracket_radius = min(0.5 * draw.uniform("bracket_diameter_mm", 4.0, 12.0), thinner)
    draw.values["bracket_diameter_mm"] = 2.0 * bracket_radius
    reach = {
        "inserted": -rng.uniform(2.0, 15.0),
        "resting": 0.9 * bracket_radius,
        "short": bracket_radius + rng.uniform(2.0, 10.0),
        "none": None,
    }[state]

    def build(hub):
        feet = hub + centred @ rotation.T
        centres = feet + post_length * x_axis
        if frame_kind == "star":
            frame = [Capsule(foot, hub, frame_radius) for foot in feet]
        elif frame_kind == "ring":
            ring = feet[np.argsort(np.arctan2(centred[:, 2], centred[:, 1]))]
            frame = [Capsule(a, b, frame_radius) for a, b in zip(ring, np.roll(ring, -1, axis=0))]
            frame += [Capsule(ring[0], ring[2], frame_radius), Capsule(hub, 0.5 * (ring[0] + ring[2]), frame_radius)]
        else:
            in_plane = centred[:, 1:]
            half = np.abs(in_plane - in_plane.mean(axis=0)).max(axis=0) + post_radius + plate_margin
            axes = np.column_stack((y_axis, rotation[:, 2], x_axis))
            centre = hub + rotation[:, 1:] @ in_plane.mean(axis=0)
            frame = [Slab(centre, axes, np.array([half[0], half[1], frame_radius]), rounding=min(2.0, frame_radius))]
        posts = [Capsule(c, f, post_radius) for c, f in zip(centres, feet)] if post_length > 0 else []
        spheres = [
            CutBall(centre, radius, x_axis, depth) if number in damaged else Ball(centre, radius)  # cap off the post
            for number, (centre, depth) in enumerate(zip(centres, cap_depths), start=1)
        ]
        return centres, frame, posts, spheres

    hub = anchor + direction * (tissue + length)
    for _ in range(5):
        centres, frame, posts, spheres = build(hub)
        deficit = tissue + BODY_CLEARANCE_MM - _clearance(bone, frame + posts + spheres)
        if deficit <= 0:
            break
        hub = hub + direction * (deficit + 2.0)
    draw.values["bracket_length_mm"] = float(np.linalg.norm(hub - anchor) - tissue)
    bracket = None if reach is None else _bracket_solid(shape, hub, anchor + reach * direction, bracket_radius)
    parts = [(bracket, bracket_hu)] if bracket is not None else []
    parts += [(solid, frame_hu) for solid in frame] + [(solid, post_hu) for solid in posts]
    parts += [(solid, sphere_hu) for solid in spheres]
    others = [solid for solid, _ in parts]
    exposed = [_exposed(sphere, [solid for solid in others if solid is not sphere]) for sphere in spheres]
    return {
        "parts": parts,
        "centres": centres,
        "markers_reference": markers_reference,
        "damaged": [number in damaged for number in range(1, len(centres) + 1)],
        "exposed": exposed,
        "bracket": bracket,
        "hub": hub,
    }


def _bracket_solid(shape, hub, end, radius):
    """The bracket from the frame's ``hub`` to ``end`` (3,) mm: a 'round' rod (a capsule of ``radius`` mm, its tip
    reaching ``radius`` past ``end``) or a 'square' bar (``radius`` the half of its side, its flat end where the
    rod's tip would be, its edges rounded by half a millimetre), turned about its axis as the grid's first axis
    allows."""
    if shape == "round":
        return Capsule(hub, end, radius)
    axis = (end - hub) / np.linalg.norm(end - hub)
    across = np.cross(axis, np.eye(3)[int(np.argmin(np.abs(axis)))])
    across /= np.linalg.norm(across)
    tip = end + radius * axis
    axes = np.column_stack((across, np.cross(axis, across), axis))
    half = np.array([radius, radius, 0.5 * float(np.linalg.norm(tip - hub))])
    return Slab(0.5 * (hub + tip), axes, half, rounding=min(0.5, radius))


def wide_bracket_overrides(seed):
    """Overrides (``make_family_ct``) for a seed's CT with a wide bracket, drawn from the seed's own stream apart
    from the CT's (the CT's other choices stay as the seed draws them): a round rod or a square bar, 8-20 mm across,
    up to WIDE_BRACKET_CAP of the bone's half-thickness, inserted into the bone or resting on it (held-out CTs:
    a 7 mm square bar inserted into a 9 mm flat bone, a 15 mm square bar resting on a 28 mm tibia)."""
    rng = np.random.default_rng([int(seed), WIDE_STREAM])
    return {
        "bracket_shape": BRACKET_SHAPES[int(rng.integers(len(BRACKET_SHAPES)))],
        "bracket_diameter_mm": float(rng.uniform(8.0, 20.0)),
        "bracket": ("inserted", "resting")[int(rng.integers(2))],
        "bracket_cap": WIDE_BRACKET_CAP,
    }


def thick_bar_overrides(seed):
    """Overrides (``make_family_ct``) for a seed's CT with a square bar nearly as thick as a thin long bone, resting
    on it and brighter than its cortex, under little noise (the held-out wide CT 3112's kind: a 12 mm square bar of
    1,096 HU resting on a long bone 13-17 mm thick whose cortex is 831 HU, 5 HU of noise), drawn from the seed's own
    stream apart from the CT's (its other choices stay as the seed draws them): a long bone of radius 6-9 mm and
    cortex 750-950 HU; a square bar 9-14 mm across (up to WIDE_BRACKET_CAP of the bone's half-thickness) of
    1,000-1,500 HU; 3-10 HU of noise."""
    rng = np.random.default_rng([int(seed), THICK_BAR_STREAM])
    return {
        "bone": "long",
        "bone_radius_mm": float(rng.uniform(6.0, 9.0)),
        "cortex_hu": float(rng.uniform(750.0, 950.0)),
        "bracket": "resting",
        "bracket_shape": "square",
        "bracket_cap": WIDE_BRACKET_CAP,
        "bracket_diameter_mm": float(rng.uniform(9.0, 14.0)),
        "bracket_hu": float(rng.uniform(1000.0, 1500.0)),
        "noise_hu": float(rng.uniform(3.0, 10.0)),
    }


def _clearance(bone, solids):
    """Least distance (mm) from the bone's surface to points sampled on the solids (their axes, centres, mid-planes,
    less their radii): how far the body stands off the bone."""
    least = np.inf
    for solid in solids:
        if isinstance(solid, Capsule):
            t = np.linspace(0.0, 1.0, 12)[:, None]
            points, reach = solid.start + t * (solid.end - solid.start), solid.radius
        elif isinstance(solid, Slab):
            u = np.linspace(-1.0, 1.0, 7)
            grid = np.array([[a, b, 0.0] for a in u for b in u]) * solid.half_size
            points, reach = solid.centre + grid @ solid.axes.T, solid.half_size[2]
        else:
            points, reach = np.asarray(solid.centre, float)[None], solid.radius
        least = min(least, float(bone.signed_distance(points).min()) - reach)
    return least


def _log_uniform(rng, low, high):
    return float(np.exp(rng.uniform(np.log(low), np.log(high))))


def _exposed(sphere, others):
    """Fraction of a sphere's surface not inside any of the ``others`` (its post, a frame it is sunk into)."""
    index = np.arange(400) + 0.5
    polar, azimuth = np.arccos(1.0 - index / 200.0), np.pi * (1.0 + 5.0**0.5) * index
    directions = np.column_stack((np.cos(azimuth) * np.sin(polar), np.sin(azimuth) * np.sin(polar), np.cos(polar)))
    points = sphere.centre + sphere.radius * directions
    covered = np.zeros(len(points), dtype=bool)
    for solid in others:
        covered |= solid.signed_distance(points) < 0.0
    return float(1.0 - covered.mean())


def _draw_grid(draw, profile, body, anchor, normal, along, bone):
    """The scanner grid (an air-filled CTVolume) and the field of view; it may cut spheres and the bone short."""
    rng = draw.rng
    radius = MARKER_DIAMETER_MM / 2.0
    in_plane = draw.uniform("in_plane_mm", 0.3, 1.0)
    across = draw("slice_mm", float(np.clip(in_plane * rng.uniform(0.6, 2.0), 0.3, 1.0)))
    spacing = np.array([in_plane, in_plane, across])
    direction = _random_rotation(rng) @ LPS_DIRECTION if draw.chance("turned", 0.5) else LPS_DIRECTION
    body_margin = draw.uniform("body_margin_mm", 3.0, 20.0)
    bone_reach = draw("bone_reach_mm", float(rng.uniform(8.0, 20.0) if rng.random() < 0.2 else rng.uniform(25.0, 70.0)))
    points = [c + s * (radius + body_margin) * e for c in body["centres"] for e in np.eye(3) for s in (-1, 1)]
    points += [body["hub"], anchor + along * bone_reach, anchor - along * bone_reach]
    if isinstance(bone, MeshSolid):
        samples, _ = bone.surface_samples()
        points += list(samples[np.linalg.norm(samples - anchor, axis=1) < bone_reach][::500])
    else:  # the bone's section under the anchor: across it (the far side of a shaft, the other table) and inward
        points += [2.0 * _centre_of(bone, anchor) - anchor, anchor - normal * bone_reach]
    along_grid = np.array(points) @ direction  # coordinates along i, j, k (mm)
    low, high = along_grid.min(axis=0) - 3.0, along_grid.max(axis=0) + 3.0
    count = int(rng.choice([0, 1, 2], p=[0.7, 0.25, 0.05]))
    cut = draw("cut_markers", [int(m) + 1 for m in rng.choice(len(body["centres"]), size=count, replace=False)])
    for number in cut:
        centre = body["centres"][number - 1] @ direction
        face = int(np.argmin(np.concatenate((centre - low, high - centre))))
        axis, side = face % 3, (-1.0 if face < 3 else 1.0)
        position = centre[axis] + side * rng.uniform(-0.7, 0.9) * radius  # the centre itself may be cut off
        if side < 0:
            low[axis] = max(low[axis], position)
        else:
            high[axis] = min(high[axis], position)
    voxels = np.prod((high - low) / spacing)
    if voxels > PROFILES[profile]:  # coarser voxels, never beyond 1 mm
        spacing = np.maximum(spacing, np.minimum(spacing * (voxels / PROFILES[profile]) ** (1.0 / 3.0), 1.0))
    shape = tuple(int(n) for n in np.floor((high - low) / spacing) + 1)
    ijk_to_ras = np.eye(4)
    ijk_to_ras[:3, :3] = direction * spacing
    ijk_to_ras[:3, 3] = direction @ low
    volume = CTVolume(voxels=np.full(shape, AIR_HU, dtype=np.float32), ijk_to_ras=ijk_to_ras)
    cylinder = draw.chance("cylinder", 0.2)
    fraction = draw.uniform("cylinder_fraction", 0.42, 0.7)
    draw.choice("padding_hu", (-1024.0, -2048.0, -3024.0))
    if not cylinder:
        return volume, FieldOfView(ijk_to_ras, shape)
    extent = np.array(shape[:2]) * spacing[:2]
    return volume, FieldOfView(ijk_to_ras, shape, tuple((np.array(shape[:2]) - 1) / 2.0), fraction * extent.max())


def _centre_of(bone, anchor):
    """A point inside an analytic bone, across from ``anchor``: the capsule's axis or the slab's mid-plane."""
    if isinstance(bone, Capsule):
        axis = bone.end - bone.start
        t = np.clip((anchor - bone.start) @ axis / (axis @ axis), 0.0, 1.0)
        return bone.start + t * axis
    local = (anchor - bone.centre) @ bone.axes
    local[np.argmin(bone.half_size)] = 0.0
    return bone.centre + bone.axes @ local


def _draw_image(draw, spacing):
    """How the CT is formed; the point spread is relative to the voxels (a CT is reconstructed on voxels about as
    fine as its resolution)."""
    return {
        "partial_volume": draw.choice("partial_volume", PARTIAL_VOLUME_MODELS, p=[0.5, 0.3, 0.2]),
        "blur_in_plane_mm": draw("blur_in_plane_mm", float(draw.rng.uniform(0.4, 0.9) * spacing[0])),
        "blur_across_mm": draw("blur_across_mm", float(draw.rng.uniform(0.4, 0.9) * spacing[2])),
        "noise_hu": draw.log_uniform("noise_hu", 2.0, 80.0),
        "noise": draw.choice("noise", ("white", "correlated"), p=[0.6, 0.4]),
        "correlation_voxels": draw.uniform("correlation_voxels", 0.5, 1.2),
        "streak_scale": draw.uniform("streak_scale", 0.3, 1.5),
    }


def _draw_clutter(draw, volume, bone, anchor, along, normal, body):
    """Bright things that are not the reference body: [(solid, HU)]: blobs, a wire, a steel pin, a spare sphere."""
    rng = draw.rng
    parts = []
    shape = np.array(volume.voxels.shape)
    spots = volume.ijk_to_ras_points(rng.uniform(0, 1, (64, 3)) * (shape - 1))
    for _ in range(draw("blobs", int(rng.poisson(1.2)))):
        spot, size = spots[rng.integers(len(spots))], rng.uniform(1.0, 4.0)
        if bone.signed_distance(spot[None])[0] > size + 1.0:  # in tissue or air, not in the bone
            parts.append((Ball(spot, size), rng.uniform(200.0, 2500.0)))
    if draw.chance("wire", 0.25):
        a, b = spots[rng.integers(len(spots), size=2)]
        parts.append((Capsule(a, b, rng.uniform(0.3, 1.2)), rng.uniform(300.0, 3071.0)))
    if draw.chance("pin", 0.15):
        start = anchor + along * rng.uniform(8.0, 25.0) * rng.choice([-1, 1]) + normal * rng.uniform(5.0, 15.0)
        parts.append((Capsule(start, start - normal * rng.uniform(25.0, 45.0), rng.uniform(2.0, 3.0)), 3071.0))
    if draw.chance("spare_sphere", 0.1):
        tissue = draw.values["tissue_mm"]
        for spot in spots:
            apart = np.linalg.norm(body["centres"] - spot, axis=1).min()
            if apart > 25.0 and bone.signed_distance(spot[None])[0] > tissue + 10.0:
                parts.append((Ball(spot, MARKER_DIAMETER_MM / 2.0), draw.values["sphere_hu"]))
                break
    return parts


def _marker_states(body, field_of_view):
    radius = MARKER_DIAMETER_MM / 2.0
    states = []
    for room, damaged, exposed in zip(field_of_view.clearance(body["centres"]), body["damaged"], body["exposed"]):
        if room < radius:
            states.append("cut")
        elif damaged:
            states.append("damaged")
        elif exposed < MIN_EXPOSED:
            states.append("hidden")
        elif room >= radius + VISIBLE_MARGIN_MM:
            states.append("visible")
        else:
            states.append("edge")
    return tuple(states)


# -- scoring the image side against the truth ------------------------------------------------------------------
#: A usable sphere within this of its marker's true centre is found (issue 27's target), else it is false.
FOUND_WITHIN_MM = 0.15
#: IPC points within this of the true bone surface are on it.
ON_BONE_MM = 0.5


@dataclass(frozen=True)
class FamilyScore:
    """How an image side did on one family CT.

    Attributes:
        visible: wholly visible spheres, in CTs that hold at least 3 of the tool's spheres (fewer cannot be told
            apart by the tool's distances, so none can be numbered: those are ``unpairable``); found: those given
            usable, with their marker's number, within ``FOUND_WITHIN_MM``; false: usable spheres farther than that
            from their marker's true centre;
            cut: spheres cut by the field of view; cut_usable: cut spheres given usable.
        ipc_points, ipc_on_bone: IPC points, and those within ``ON_BONE_MM`` of the true bone surface;
        ipc_on_body: IPC points off the bone and within 1 mm of the reference body or its bracket.
        coverage: fraction of the true bone surface in view (3 mm or more from the body) with an IPC point
            within 1 mm (metal zones and the ring round a bracket are left out of the IPC on purpose).
        refused: the image side's refusal message, or ''.
        bone_in_view_mm3: with a refusal, the bone's volume inside the field of view (``rightly_refused``).
    """

    visible: int
    found: int
    false: int
    cut: int
    cut_usable: int
    ipc_points: int
    ipc_on_bone: int
    ipc_on_body: int
    coverage: float
    refused: str = ""
    unpairable: int = 0
    bone_in_view_mm3: float = float("nan")

    @property
    def rightly_refused(self):
        """A refusal where the bone inside the field of view is smaller than any object taken for bone
        (``bone_recognition.MIN_BONE_MM3``): no bone to give a surface of."""
        from ..image.bone_recognition import MIN_BONE_MM3

        return bool(self.refused) and self.bone_in_view_mm3 < MIN_BONE_MM3


def score_image_side(volume, truth, image=None, refused="", usable=()):
    """Score an ``ImageSideResult`` (or a refusal message, with ``image`` None, and the ``usable`` marker spheres the
    refusal gave all the same: ``ct_pipeline.NoBoneSurface.usable``) against a FamilyTruth."""
    from scipy.spatial import cKDTree

    visible, cut = truth.visible, truth.cut
    in_view = sum(state in ("visible", "edge", "hidden") for state in truth.marker_states)
    unpairable = 0
    if in_view < 3:
        unpairable, visible = int(visible.sum()), np.zeros_like(visible)
    found = false = cut_usable = 0
    for sphere in usable if image is None else image.usable:
        error = np.linalg.norm(sphere.centre - truth.marker_centres[sphere.number - 1])
        if error <= FOUND_WITHIN_MM and visible[sphere.number - 1]:
            found += 1
        elif error > FOUND_WITHIN_MM:
            false += 1
        cut_usable += bool(cut[sphere.number - 1])
    if image is None:
        bone_mm3 = truth.bone_in_view_mm3(volume) if refused else float("nan")
        return FamilyScore(
            int(visible.sum()), found, false, int(cut.sum()), cut_usable, 0, 0, 0, 0.0, refused, unpairable, bone_mm3
        )
    points = image.surface.points
    on_bone = truth.bone_distance(points) <= ON_BONE_MM
    on_body = ~on_bone & (truth.body_distance(points) <= 1.0)
    surface = truth.bone_surface_points(volume, spacing_mm=2.0)
    surface = surface[truth.body_distance(surface) > 3.0]
    covered = cKDTree(points).query(surface, distance_upper_bound=1.0)[0] < np.inf if len(surface) else []
    return FamilyScore(
        visible=int(visible.sum()),
        found=found,
        false=false,
        cut=int(cut.sum()),
        cut_usable=cut_usable,
        ipc_points=len(points),
        ipc_on_bone=int(on_bone.sum()),
        ipc_on_body=int(on_body.sum()),
        coverage=float(np.mean(covered)) if len(surface) else 1.0,
        unpairable=unpairable,
    )
