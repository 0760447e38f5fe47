"""The image side's results as real MRML nodes (slicer-core): segmentation, IPC model, marker fiducials."""

import numpy as np
import pytest

from RAMSICPRegistrationLib.image.ct_segmentation import bone_surface, segment_bone
from RAMSICPRegistrationLib.image.marker_spheres import detect_marker_spheres
from RAMSICPRegistrationLib.image.volume_io import load_volume

from conftest import analytic_volume, sphere_sdf

slicer = pytest.importorskip("slicer", reason="slicer-core (real MRML) needs Python >= 3.10")
from RAMSICPRegistrationLib.navigation import mrml_nodes  # noqa: E402

CENTRE = np.array([10.0, -20.0, 30.0])


@pytest.fixture
def scene():
    return slicer.vtkMRMLScene()


@pytest.fixture(scope="module")
def bone_and_sphere():
    shapes = [(sphere_sdf(CENTRE, 10.0), 1400.0), (sphere_sdf(CENTRE + (0.0, 0.0, 20.0), 5.75), 700.0)]
    volume = analytic_volume(shapes, size_mm=(30.0, 30.0, 50.0), centre=CENTRE + (0.0, 0.0, 8.0), noise_hu=10.0)
    segmentation = segment_bone(volume)
    return volume, segmentation, detect_marker_spheres(volume, segmentation, expected=1)


def test_volume_node_round_trip(scene, bone_and_sphere):
    volume, _, _ = bone_and_sphere
    node = mrml_nodes.volume_node(scene, volume, "CT")
    loaded = load_volume(node)
    np.testing.assert_allclose(loaded.ijk_to_ras, volume.ijk_to_ras, atol=1e-12)
    np.testing.assert_array_equal(loaded.voxels, volume.voxels)


def test_segmentation_node_has_bone_and_marker_segments(scene, bone_and_sphere):
    volume, segmentation, detection = bone_and_sphere
    import dataclasses

    sphere = dataclasses.replace(detection.spheres[0], number=2)  # paired with the tool's second marker
    node = mrml_nodes.segmentation_node(scene, volume, segmentation, [sphere])
    segments = node.GetSegmentation()
    assert [segments.GetNthSegment(i).GetName() for i in range(segments.GetNumberOfSegments())] == ["bone", "marker 2"]
    # Export back to a labelmap on the CT's grid: the voxels are the segmentation's, voxel for voxel.
    reference = mrml_nodes.volume_node(scene, volume, "reference")
    exported = scene.AddNewNodeByClass("vtkMRMLLabelMapVolumeNode")
    assert slicer.vtkSlicerSegmentationsModuleLogic.ExportVisibleSegmentsToLabelmapNode(node, exported, reference)
    labels = load_volume_labels(exported)
    assert np.count_nonzero(labels == 1) == np.count_nonzero(segmentation.bone_mask)
    assert np.count_nonzero(labels == 2) == np.count_nonzero(segmentation.labels == sphere.label)
    # Only the export above is a labelmap node: the temporary one used for the import is gone.
    assert scene.GetNodesByClass("vtkMRMLLabelMapVolumeNode").GetNumberOfItems() == 1


def load_volume_labels(node):
    from vtkmodules.util.numpy_support import vtk_to_numpy

    image = node.GetImageData()
    return vtk_to_numpy(image.GetPointData().GetScalars()).reshape(image.GetDimensions()[::-1]).transpose(2, 1, 0)


def test_model_node_holds_the_ipc(scene, bone_and_sphere):
    volume, segmentation, _ = bone_and_sphere
    surface = bone_surface(volume, segmentation)
    node = mrml_nodes.model_node(scene, surface.points, surface.triangles)
    assert node.GetPolyData().GetNumberOfPoints() == len(surface.points)
    assert node.GetPolyData().GetNumberOfPolys() == len(surface.triangles)
    cloud = mrml_nodes.model_node(scene, surface.points[:100], name="thinned")
    assert cloud.GetPolyData().GetNumberOfVerts() == 100


def test_fiducials_are_11_5_mm_spheres_that_can_be_moved(scene, bone_and_sphere):
    _, _, detection = bone_and_sphere
    centres = np.array([sphere.centre for sphere in detection.spheres])
    node = mrml_nodes.fiducial_node(scene, centres, ["M1 ok"])
    np.testing.assert_allclose(mrml_nodes.fiducial_positions(node), centres)
    np.testing.assert_allclose(centres[0], CENTRE + (0.0, 0.0, 20.0), atol=0.05)
    assert node.GetDisplayNode().GetGlyphSize() == 11.5 and node.GetNthControlPointLabel(0) == "M1 ok"
    node.SetNthControlPointPosition(0, 1.0, 2.0, 3.0)  # the surgeon drags it
    np.testing.assert_allclose(mrml_nodes.fiducial_positions(node), [[1.0, 2.0, 3.0]])
