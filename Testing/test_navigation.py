"""The Slicer module's workflow, step by step, on real MRML (slicer-core) and the tibia CT phantom.

The workflow runs through the shared scenario (the module's self-test) on the controller; the probe is simulated
as SlicerIGT's self-tests do, by writing matrices into the transform nodes. The controller's event handling has
its own tests in ``test_controller.py``.
"""

import json

import numpy as np
import pytest

from RAMSICPRegistrationLib.core.registration import DEFAULT_METHOD
from RAMSICPRegistrationLib.core.transforms import (
    apply_transform,
    invert_transform,
    make_transform,
)

from conftest import headless_scene, random_transform

slicer = pytest.importorskip("slicer", reason="slicer-core (real MRML) needs Python >= 3.10")
from RAMSICPRegistrationLib.navigation import mrml_nodes  # noqa: E402
from RAMSICPRegistrationLib.navigation.navigation import NavigationLogic, load_scene, matrix_of, set_matrix  # noqa: E402
from RAMSICPRegistrationLib.navigation.scenarios import TIP_IN_PROBE, check_workflow, run_workflow  # noqa: E402

TIP = TIP_IN_PROBE  # probe tip offset in the probe frame (mm)


@pytest.fixture(scope="module")
def workflow(tibia_phantom, tibia_patient, tmp_path_factory):
    """Steps 1-4 run once on the phantom through the shared scenario; the tests below check each step."""
    volume, truth = tibia_phantom
    folder = tmp_path_factory.mktemp("autosave")
    state = run_workflow(headless_scene(), tibia_patient, volume, truth, autosave_directory=folder)
    return {**state, "folder": folder}


def test_the_slicer_self_test_scenario_passes(workflow):
    figures = check_workflow(workflow)  # exactly what the module's Test class runs inside Slicer
    assert figures["marker_error_mm"] < 0.1 and figures["target_error_mm"] < 0.3


def test_step1_image_nodes(workflow):
    image, truth = workflow["image"], workflow["truth"]
    segments = image.segmentation.GetSegmentation()
    assert segments.GetNumberOfSegments() == 5  # bone and 4 spheres
    assert image.ipc_model.GetPolyData().GetNumberOfPoints() > 80_000
    centres = mrml_nodes.fiducial_positions(image.markers_image)
    np.testing.assert_allclose(centres, truth.marker_centres, atol=0.1)  # automatic, in the tool's order
    assert image.markers_image.GetDisplayNode().GetGlyphSize() == 11.5 and image.warnings == ()


def test_step2_hierarchy_and_pivot(workflow):
    nodes = workflow["nodes"]
    np.testing.assert_allclose(matrix_of(nodes["tip"])[:3, 3], TIP, atol=1e-9)
    assert workflow["pivot"].rms_mm < 1e-9
    assert nodes["tip"].GetParentTransformNode() is nodes["probe"]
    assert nodes["probe"].GetParentTransformNode() is nodes["reference_to_image"]


def test_step3_points_are_collected_and_saved_at_once(workflow):
    ppc_node, trial = workflow["nodes"]["ppc"], workflow["trial"]
    np.testing.assert_allclose(mrml_nodes.fiducial_positions(ppc_node), trial.ppc, atol=1e-9)
    saved = json.loads((workflow["folder"] / "ProbePoints.mrk.json").read_text())
    assert len(saved["markups"][0]["controlPoints"]) == len(trial.ppc)
    markers_patient = mrml_nodes.fiducial_positions(workflow["nodes"]["markers_patient"])
    np.testing.assert_allclose(markers_patient, workflow["patient"].markers_reference)  # the tool geometry


def test_step4_registration_result_nodes(workflow):
    result, patient = workflow["result"], workflow["patient"]
    computed = matrix_of(workflow["nodes"]["reference_to_image"])
    np.testing.assert_allclose(computed, result.reference_to_image)
    targets = apply_transform(invert_transform(patient.reference_to_image), patient.targets_image)
    errors = np.linalg.norm(apply_transform(computed, targets) - patient.targets_image, axis=1)
    assert errors.max() < 0.3  # automatic centres and exact touches: only the CT's own error remains
    parameters = workflow["controller"].parameters
    assert parameters.residualTable.GetNumberOfRows() == 40
    assert parameters.referenceToImage is workflow["nodes"]["reference_to_image"]
    assert float(parameters.node.GetParameter("FreMm")) == pytest.approx(result.fre_mm)
    logic, nodes, image = workflow["logic"], workflow["nodes"], workflow["image"]
    arguments = (image.ipc_model, nodes["ppc"], image.markers_image, nodes["markers_patient"])
    logic.register(*arguments, method="cr-ramsicp")  # the sweep plot belongs to RAMSICP
    assert parameters.sweepChart.GetNumberOfPlotSeriesNodes() == 1  # RMS (no targets given)
    logic.register(*arguments)  # back to the default method for the later steps


def test_step4_excluding_a_point_reruns_without_it(workflow):
    logic, nodes, image = workflow["logic"], workflow["nodes"], workflow["image"]
    logic.set_included(7, False)
    result = logic.register(image.ipc_model, nodes["ppc"], image.markers_image, nodes["markers_patient"])
    assert len(result.residuals_mm) == 39
    table = workflow["controller"].parameters.residualTable.GetTable()
    assert np.isnan(table.GetColumnByName("residual_mm").GetValue(7))
    assert table.GetColumnByName("include").GetValue(7) == 0
    logic.set_included(7, True)


def untick_in_slicers_table_view(table_node, row, column_name, checked):
    """What qMRMLTableModel::updateMRMLFromItem does when the surgeon clicks a tick box in a vtkBitArray column
    (Slicer v5.6.0-v5.10.0, Libs/MRML/Widgets/qMRMLTableModel.cxx): it writes the item's Qt::CheckState (0
    unchecked, 2 checked) as a vtkVariant into the cell, then marks the column and the table modified."""
    from vtkmodules.vtkCommonCore import vtkVariant

    table = table_node.GetTable()
    column = next(index for index in range(table.GetNumberOfColumns()) if table.GetColumnName(index) == column_name)
    table.SetValue(row, column, vtkVariant(2 if checked else 0))
    table.GetColumn(column).Modified()
    table.Modified()


def test_step4_the_include_column_is_tick_boxes_and_unticking_one_leaves_it_out(workflow):
    """Slicer's table view shows tick boxes only for a vtkBitArray column; a click writes 0 or 2 into it."""
    controller = workflow["controller"]
    table_node = controller.parameters.residualTable
    include = table_node.GetTable().GetColumnByName("include")
    assert include.IsA("vtkBitArray") and include.GetNumberOfTuples() == 40
    assert all(include.GetValue(row) == 1 for row in range(40))
    untick_in_slicers_table_view(table_node, 12, "include", checked=False)
    result = controller.run("register")
    assert len(result.residuals_mm) == 39
    table = controller.parameters.residualTable.GetTable()
    assert np.isnan(table.GetColumnByName("residual_mm").GetValue(12))
    assert table.GetColumnByName("include").IsA("vtkBitArray") and table.GetColumnByName("include").GetValue(12) == 0
    untick_in_slicers_table_view(table_node, 12, "include", checked=True)
    assert table.GetColumnByName("include").GetValue(12) == 1  # Qt::Checked (2) stored as a bit
    assert len(controller.run("register").residuals_mm) == 40


def test_step5_tip_to_surface_distance(workflow):
    logic, nodes, patient = workflow["logic"], workflow["nodes"], workflow["patient"]
    on_bone = apply_transform(invert_transform(patient.reference_to_image), patient.targets_image[:1])[0]
    set_matrix(nodes["probe"], make_transform(translation=on_bone - TIP))
    distance = logic.tip_to_surface_mm(
        workflow["image"].ipc_model, nodes["probe"], nodes["tip"], nodes["reference_to_image"]
    )
    assert distance < 0.5


def test_step6_robot_nodes(workflow):
    logic, nodes = workflow["logic"], workflow["nodes"]
    rng = np.random.default_rng(9)
    truth = random_transform(rng, max_translation_mm=800.0)
    robot_points = np.array([[300.0, 0.0, 200.0], [360.0, 10.0, 200.0], [310.0, 70.0, 230.0]])
    reference_to_tracker = logic.transform_node("ReferenceToTracker")
    set_matrix(reference_to_tracker, workflow["reference_to_tracker"])
    base_node, image_node = logic.robot_calibration(
        robot_points, apply_transform(truth, robot_points), reference_to_tracker, nodes["reference_to_image"]
    )
    np.testing.assert_allclose(matrix_of(base_node), truth, atol=1e-9)
    expected = (
        invert_transform(truth)
        @ workflow["reference_to_tracker"]
        @ invert_transform(matrix_of(nodes["reference_to_image"]))
    )
    np.testing.assert_allclose(matrix_of(image_node), expected, atol=1e-9)


def test_step7_save_and_reload_reproduce_the_registration(workflow, tmp_path):
    logic, nodes, image = workflow["logic"], workflow["nodes"], workflow["image"]
    before = logic.register(image.ipc_model, nodes["ppc"], image.markers_image, nodes["markers_patient"])
    written = logic.save(tmp_path / "scene.mrml")
    assert (tmp_path / "scene.mrml").is_file() and len(written) > 5
    reloaded = load_scene(headless_scene(), tmp_path / "scene.mrml")
    original = matrix_of(workflow["nodes"]["reference_to_image"])
    # Slicer stores linear transforms as ITK HDF5 in LPS, inverted: the round trip is exact to float rounding.
    np.testing.assert_allclose(matrix_of(reloaded.GetFirstNodeByName("ReferenceToImage")), original, rtol=0, atol=1e-9)
    again = NavigationLogic(reloaded)
    result = again.register(
        reloaded.GetFirstNodeByName("IPC"),
        reloaded.GetFirstNodeByName("ProbePoints"),
        reloaded.GetFirstNodeByName("MarkersImage"),
        reloaded.GetFirstNodeByName("MarkersPatient"),
    )
    np.testing.assert_allclose(result.reference_to_image, before.reference_to_image, rtol=0, atol=1e-9)
    assert again.parameter_node.GetParameter("Method") == DEFAULT_METHOD
    assert again.parameters.referenceToImage.GetName() == "ReferenceToImage"  # the references survive a reload


def _node_data(node):
    """What a node holds, as arrays and text, for comparing a scene with its reloaded copy."""
    from vtkmodules.util.numpy_support import vtk_to_numpy

    if node.IsA("vtkMRMLTransformNode"):
        return {"matrix": matrix_of(node)}
    if node.IsA("vtkMRMLMarkupsNode"):
        count = node.GetNumberOfControlPoints()
        labels = [node.GetNthControlPointLabel(index) for index in range(count)]
        return {"positions": mrml_nodes.fiducial_positions(node), "labels": labels}
    if node.IsA("vtkMRMLModelNode"):
        data = node.GetPolyData()
        return {"points": vtk_to_numpy(data.GetPoints().GetData()).astype(np.float64), "cells": data.GetNumberOfCells()}
    if node.IsA("vtkMRMLTableNode"):
        table = node.GetTable()
        columns = [table.GetColumn(index) for index in range(table.GetNumberOfColumns())]
        return {
            column.GetName(): (
                column.GetDataTypeAsString(),
                [table.GetValue(row, index).ToString() for row in range(table.GetNumberOfRows())],
            )
            for index, column in enumerate(columns)
        }
    if node.IsA("vtkMRMLScalarVolumeNode"):
        from RAMSICPRegistrationLib.image.volume_io import volume_from_node

        volume = volume_from_node(node)
        return {"voxels": volume.voxels, "ijk_to_ras": volume.ijk_to_ras}
    if node.IsA("vtkMRMLSegmentationNode"):
        segmentation, found = node.GetSegmentation(), {}
        for index in range(segmentation.GetNumberOfSegments()):
            segment_id = segmentation.GetNthSegmentID(index)
            segment = segmentation.GetSegment(segment_id)
            image = node.GetBinaryLabelmapInternalRepresentation(segment_id)
            voxels = vtk_to_numpy(image.GetPointData().GetScalars())
            found[segment.GetName()] = int((voxels == segment.GetLabelValue()).sum())
        return found
    return None


def _assert_same(original, reloaded, path):
    for key, value in original.items():
        if isinstance(value, np.ndarray):
            np.testing.assert_allclose(reloaded[key], value, rtol=0, atol=1e-6, err_msg=f"{path}: {key}")
        else:
            assert reloaded[key] == value, f"{path}: {key}"


@pytest.mark.parametrize("suffix", [".mrb", ".mrml"])
def test_step7_the_modules_save_reloads_every_node_with_its_data(workflow, tmp_path, suffix):
    """The Slicer module saves through the controller (``run('save', path)``): as one .mrb (Slicer's own
    vtkMRMLScene::WriteToMRB) or as .mrml with its data files. Read back as Slicer reads them (ReadFromMRB, or
    the scene and its storage nodes), every node the session made is there with its data: the CT, the
    segmentation's segments and voxels, the IPC's points, every markups point and label (probe points, marker
    centres, targets), every matrix, the residual table with its tick-box column."""
    controller = workflow["controller"]
    scene = workflow["scene"]
    saved = {}
    for index in range(scene.GetNumberOfNodes()):
        node = scene.GetNthNode(index)
        data = _node_data(node)
        if data is not None and not node.GetHideFromEditors():
            saved[(node.GetClassName(), node.GetName())] = data
    kinds = {kind for kind, _ in saved}
    assert {"vtkMRMLScalarVolumeNode", "vtkMRMLSegmentationNode", "vtkMRMLModelNode", "vtkMRMLTableNode"} <= kinds
    assert {"vtkMRMLMarkupsFiducialNode", "vtkMRMLLinearTransformNode"} <= kinds
    path = tmp_path / f"session{suffix}"
    written = controller.run("save", path)
    assert written is not None and written[0] == path, controller.status().message
    reloaded = load_scene(headless_scene(), path)
    for (kind, name), data in saved.items():
        node = reloaded.GetFirstNode(name, kind, None, False)
        assert node is not None and node.GetClassName() == kind, f"{path}: {kind} {name!r} is missing"
        _assert_same(data, _node_data(node), f"{path}: {name}")
    assert reloaded.GetFirstNodeByName("RegistrationResiduals").GetTable().GetColumnByName("include").IsA("vtkBitArray")


def test_saving_somewhere_wrong_is_a_message(workflow, tmp_path):
    controller = workflow["controller"]
    assert controller.run("save", tmp_path / "session.txt") is None
    assert controller.status().message == (
        f"{tmp_path / 'session.txt'}: give a file name ending in .mrb (one file) or .mrml (the scene and its data "
        "files beside it)"
    )
    (tmp_path / "folder.mrb").mkdir()
    assert controller.run("save", tmp_path / "folder.mrb") is None
    assert controller.status().message == f"{tmp_path / 'folder.mrb'} is a folder; give a file name ending in .mrb"


def test_bad_nodes_and_inputs_say_what_to_do(workflow):
    logic, nodes, image, scene = workflow["logic"], workflow["nodes"], workflow["image"], workflow["scene"]
    with pytest.raises(TypeError, match="expected a linear transform node"):
        logic.build_hierarchy(nodes["ppc"], nodes["probe"], nodes["reference_to_image"])
    two = scene.AddNewNodeByClass("vtkMRMLMarkupsFiducialNode", "TwoMarkers")
    two.AddControlPoint([0.0, 0.0, 0.0], "a")
    two.AddControlPoint([10.0, 0.0, 0.0], "b")
    with pytest.raises(ValueError, match="needs at least 3 marker centres"):
        logic.register(image.ipc_model, nodes["ppc"], two, nodes["markers_patient"])
    with pytest.raises(TypeError, match="expected a markups or model node"):
        logic.register(nodes["ct"], nodes["ppc"], image.markers_image, nodes["markers_patient"])
    air = mrml_nodes.volume_node(scene, _air_volume(), "Air")
    with pytest.raises(ValueError, match="no voxel is above the threshold"):
        logic.process_ct(air)


def _air_volume():
    from RAMSICPRegistrationLib.image.volume_io import CTVolume

    return CTVolume(voxels=np.full((20, 20, 20), -1000, np.int16), ijk_to_ras=np.diag([0.5, 0.5, 0.625, 1.0]))
