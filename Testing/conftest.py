"""Shared fixtures: known transforms and analytic surfaces whose answers can be computed by hand."""

import os
import tempfile

# What the product caches in the user's cache folder (the demo's CT phantom, the IPC's display copy) goes into a
# fresh folder of this test run, for this process and the commands it starts: tests never read or fill the user's.
os.environ["RAMSICP_CACHE_DIR"] = tempfile.mkdtemp(prefix="ramsicp-test-cache-")

import contextlib

import numpy as np
import pytest

from RAMSICPRegistrationLib.core.transforms import make_transform, rotation_about_axis


def random_transform(rng, max_angle_deg=180.0, max_translation_mm=100.0):
    """A random rigid (4, 4) transform."""
    axis = rng.normal(size=3)
    angle = np.radians(rng.uniform(-max_angle_deg, max_angle_deg))
    return make_transform(rotation_about_axis(axis, angle), rng.uniform(-max_translation_mm, max_translation_mm, 3))


def ellipsoid_points(count, semi_axes=(40.0, 25.0, 15.0), seed=0):
    """(count, 3) points on an ellipsoid surface (mm): a closed surface that fixes all six pose parameters."""
    rng = np.random.default_rng(seed)
    directions = rng.normal(size=(count, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    return directions * np.asarray(semi_axes)


#: Radius (mm) of the analytic cylinder the osteotomy tests cut.
CYLINDER_RADIUS_MM = 15.0


def cylinder_mesh(radius=CYLINDER_RADIUS_MM, segments=720, rings=28, height=100.0):
    """Vertices on the cylinder x^2 + y^2 = radius^2, 0 <= z <= height, and the triangles of its side wall. The
    rings are 3.7 mm apart, so no cut plane of these tests passes through a vertex."""
    angles = np.radians(np.arange(segments) * 360.0 / segments)
    heights = np.linspace(0.0, height, rings)
    vertices = np.array([(radius * np.cos(a), radius * np.sin(a), z) for z in heights for a in angles])
    triangles = []
    for ring in range(rings - 1):
        for k in range(segments):
            a, b = ring * segments + k, ring * segments + (k + 1) % segments
            triangles += [(a, b, a + segments), (b, b + segments, a + segments)]
    return vertices, np.array(triangles)


def cylinder_cloud(count=300_000, radius=CYLINDER_RADIUS_MM, height=100.0, seed=0):
    """(count, 3) points uniformly on the same cylinder's side wall (21 a mm^2 by default)."""
    rng = np.random.default_rng(seed)
    angles, heights = rng.uniform(0, 2 * np.pi, count), rng.uniform(0, height, count)
    return np.column_stack((radius * np.cos(angles), radius * np.sin(angles), heights))


@pytest.fixture
def rng():
    return np.random.default_rng(12345)


@pytest.fixture(scope="session")
def tibia_patient():
    """The demo's virtual patient: the shipped right tibia with an NDI 8700339 reference body."""
    from RAMSICPRegistrationLib.simulation.package_data import shipped_patient

    return shipped_patient("right-tibia")[0]


@pytest.fixture(scope="session")
def ilium():
    """The right ilium's virtual patient (probe points on the lateral face of the wing), with its mesh."""
    from RAMSICPRegistrationLib.simulation.package_data import shipped_patient

    return shipped_patient("right-ilium")


@pytest.fixture(scope="session")
def tibia_index(tibia_patient):
    from RAMSICPRegistrationLib.core.surface_index import SurfaceIndex

    return SurfaceIndex(tibia_patient.ipc)


def analytic_volume(
    shapes,
    spacing=(0.5, 0.5, 0.625),
    size_mm=(40.0, 40.0, 40.0),
    rotation_deg=0.0,
    background_hu=-1000.0,
    noise_hu=0.0,
    blur_mm=0.3,
    seed=0,
    centre=(10.0, -20.0, 30.0),
):
    """A CT volume of analytic objects with exact partial volume, on a grid that may be rotated.

    ``shapes`` is a list of ``(signed_distance_function, hu)``; each function maps (..., 3) RAS points (mm) to
    a signed distance (negative inside). The grid is centred on ``centre`` (RAS), its axes turned by
    ``rotation_deg`` about (1, 1, 1) from L, P, S (an LPS-aligned scanner grid).
    """
    from scipy import ndimage

    from RAMSICPRegistrationLib.core.transforms import rotation_about_axis
    from RAMSICPRegistrationLib.image.volume_io import CTVolume

    spacing = np.asarray(spacing, dtype=np.float64)
    shape = np.ceil(np.asarray(size_mm) / spacing).astype(int)
    direction = rotation_about_axis((1.0, 1.0, 1.0), np.radians(rotation_deg)) @ np.diag([-1.0, -1.0, 1.0])
    ijk_to_ras = np.eye(4)
    ijk_to_ras[:3, :3] = direction * spacing
    ijk_to_ras[:3, 3] = np.asarray(centre) - ijk_to_ras[:3, :3] @ ((shape - 1) / 2.0)
    volume = CTVolume(voxels=np.zeros(tuple(shape), np.float32), ijk_to_ras=ijk_to_ras)
    grid = np.stack(np.meshgrid(*[np.arange(n) for n in shape], indexing="ij"), axis=-1).reshape(-1, 3)
    ras = volume.ijk_to_ras_points(grid).reshape(tuple(shape) + (3,))
    voxels = np.full(tuple(shape), background_hu, dtype=np.float64)
    ramp = float(np.mean(spacing))
    for signed_distance, hu in shapes:
        fraction = np.clip(0.5 - signed_distance(ras) / ramp, 0.0, 1.0)
        voxels = fraction * hu + (1.0 - fraction) * voxels
    if blur_mm > 0:
        voxels = ndimage.gaussian_filter(voxels, blur_mm / spacing)
    voxels += np.random.default_rng(seed).normal(scale=noise_hu, size=voxels.shape) if noise_hu else 0.0
    return CTVolume(voxels=voxels.astype(np.float32), ijk_to_ras=ijk_to_ras)


def damage_npz(path, edit=None):
    """Damage a cache file (``.npz``) as a crash or another version would: cut it in half when ``edit`` is None,
    else rewrite it whole with ``edit(arrays)`` applied to its arrays (a dict, changed in place)."""
    if edit is None:  # a write cut short by a crash of an older version, a full disk
        path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
        return
    with np.load(path) as stored:
        arrays = dict(stored)
    edit(arrays)
    with open(path, "wb") as stream:
        np.savez(stream, **arrays)


def sphere_sdf(centre, radius):
    centre = np.asarray(centre, dtype=np.float64)
    return lambda points: np.linalg.norm(points - centre, axis=-1) - radius


@pytest.fixture(scope="session")
def tibia_phantom(tibia_patient):
    """The demo's CT phantom of the right tibia, with its ground truth (built once: about 8 s)."""
    from RAMSICPRegistrationLib.simulation.ct_phantom import make_ct_phantom
    from RAMSICPRegistrationLib.simulation.package_data import bone_mesh

    return make_ct_phantom(tibia_patient, *bone_mesh("right-tibia"), seed=0)


def headless_scene():
    """A real vtkMRMLScene as Slicer's application sets it up for markups (selection node, markups logic)."""
    import slicer

    scene = slicer.vtkMRMLScene()
    selection = slicer.vtkMRMLSelectionNode()
    selection.SetSingletonTag("Singleton")
    scene.AddNode(selection)
    logic = slicer.vtkSlicerMarkupsLogic()
    logic.SetMRMLScene(scene)
    scene._markups_logic = logic  # keep the logic alive as long as the scene
    return scene


#: The paper's Fig. 8 ("Reproducibility"): mean and SD of the TRE (mm) over 15 subjects.
PAPER_FIG8_MM = {"CR": (1.33, 0.27), "CR-ICP": (0.89, 0.14), "CR-RAMSICP": (0.56, 0.08)}


@contextlib.contextmanager
def recorded_trials(module):
    """Record every ``(index, data, markers_image)`` that ``module`` passes to ``evaluate_trial``, which still runs.

    Yields the list the calls are appended to, so a test can register the same trials again its own way.
    """
    calls = []
    evaluate_trial = module.evaluate_trial

    def recording(index, data, markers_image=None):
        calls.append((index, data, markers_image))
        return evaluate_trial(index, data, markers_image)

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(module, "evaluate_trial", recording)
        yield calls


def register_every_way(index, data, markers_image=None):
    """One simulated trial (a TrialData) registered again by each method and policy, straight through ``register``.

    Returns the TRE (mm, eq. 11) under 'CR', 'CR-ICP', 'cr-icp-plane', 'fixed L = 5' (a single RAMSICP run at L = 5),
    'rms-plateau' (a sweep chosen by that policy, its L under 'rms-plateau L'), 'sweep' (the TRE at every L of the
    sweep, (21,)), "paper's L" (the sweep's minimum, its L under "paper's L value") and 'cr-fused'.
    """
    from RAMSICPRegistrationLib.core.registration import register

    markers = data.markers_image if markers_image is None else markers_image

    def again(method, **options):
        targets = (data.targets_image, data.targets_patient)
        return register(index, data.ppc, markers, data.markers_patient, *targets, method=method, **options)

    plateau = again("cr-ramsicp", sweep=True, policy="rms-plateau")
    sweep = np.array([entry.tre_mm for entry in plateau.sweep])
    return {
        "CR": again("cr").tre_mm,
        "CR-ICP": again("cr-icp").tre_mm,
        "cr-icp-plane": again("cr-icp-plane").tre_mm,
        "fixed L = 5": again("cr-ramsicp", scale=5.0).tre_mm,
        "rms-plateau": plateau.tre_mm,
        "rms-plateau L": plateau.scale,
        "sweep": sweep,
        "paper's L": float(sweep.min()),
        "paper's L value": plateau.sweep[int(np.argmin(sweep))].scale,
        "cr-fused": again("cr-fused").tre_mm,
    }
