"""The browser view's parts without a browser, each against an answer computed by hand: the sweep plot's pixels,
the panel's figures, the residual spheres and the needle, the command line's bad input, scene files, the
controller's pose events and tip position, and the simulated probe's pivot phase."""

import socket
import sys
import zipfile

import numpy as np
import pytest

from OpenIGTLinkBridgeLib.live_scenario import (
    PROBE_TIP_MM,
    HandHeldProbe,
    TouchScript,
    pivot_pose,
)
from RAMSICPRegistrationLib.core.pivot import pivot_calibration
from RAMSICPRegistrationLib.web.sweep_plot import sweep_svg

from conftest import headless_scene

needs_slicer = pytest.mark.skipif(sys.version_info < (3, 10), reason="slicer-core and trame-slicer need Python >= 3.10")


# -- pure parts ----------------------------------------------------------------------------------------------------
def test_sweep_plot_puts_each_value_at_its_pixel():
    svg = sweep_svg([1.0, 2.0, 3.0], {"RMS": [1.0, 0.5, 1.0], "TRE": None}, chosen_scale=2.0)
    # x from 38 (L = 1) to 290 (L = 3); y from 120 (0 mm) up to 12 (1.1 x the largest value, 1.1 mm).
    assert '<polyline points="38.0,21.8 164.0,70.9 290.0,21.8"' in svg
    assert svg.count("<polyline") == 1, "a series without values is left out"
    assert 'x1="164.0" y1="12" x2="164.0" y2="120"' in svg, "the chosen L is marked"
    assert sweep_svg([], {"RMS": []}) == ""


def test_figures_are_shown_to_the_hundredth_of_a_millimetre_and_never_as_minus_zero():
    from RAMSICPRegistrationLib.web.panel_state import millimetres

    assert millimetres(0.125) == "0.12" and millimetres(1.0 / 3.0, 1) == "0.3"
    assert millimetres(-0.001) == "0.00" and millimetres(-0.006) == "-0.01"
    assert millimetres(None) == ""


def test_the_pivot_phase_swivels_about_a_fixed_tip_that_a_pivot_calibration_recovers():
    points = np.array([[10.0, 20.0, 30.0], [40.0, 50.0, 60.0]])
    script = TouchScript(points, np.eye(4), dwell_s=1.0, move_s=0.5, start_s=0.5, pivot_s=4.0, loop=True)
    poses = np.array([script.probe_to_reference(t) for t in np.linspace(0.0, 3.99, 120)])
    tips = poses[:, :3, :3] @ PROBE_TIP_MM + poses[:, :3, 3]
    assert np.abs(tips - points[0]).max() < 1e-9, "the tip must rest in the divot while the probe swivels"
    result = pivot_calibration(poses)
    np.testing.assert_allclose(result.tip_in_probe, PROBE_TIP_MM, atol=1e-6)
    assert result.rotation_range_deg > 30
    start, end = script.touch_interval(1)
    assert (start, end) == (4.0 + 0.5 + 1.5 + 0.5, 4.0 + 0.5 + 3.0)  # after the pivot, the timeline as before
    dwelling = script.probe_to_reference((start + end) / 2)
    np.testing.assert_allclose(dwelling[:3, :3] @ PROBE_TIP_MM + dwelling[:3, 3], points[1], atol=1e-9)
    np.testing.assert_allclose(script.probe_to_reference(1.0 + script.duration_s), script.probe_to_reference(1.0))


def test_a_hand_held_probe_puts_its_tip_where_it_is_told_in_tracker_coordinates():
    reference_to_tracker = np.eye(4)
    reference_to_tracker[:3, 3] = (5.0, -7.0, -1500.0)
    probe = HandHeldProbe(reference_to_tracker)
    point = np.array([1.0, 2.0, 3.0])
    probe.touch(point)
    probe_to_tracker = probe.poses(0.0)[probe.probe_rom]
    np.testing.assert_allclose(
        probe_to_tracker[:3, :3] @ PROBE_TIP_MM + probe_to_tracker[:3, 3], point + (5, -7, -1500)
    )
    probe.slide(point, point + (0.0, 40.0, 0.0), period_s=2.0)
    halfway = probe.poses(0.5)[probe.probe_rom]  # a quarter period: half-way along the 40 mm
    np.testing.assert_allclose(halfway[:3, :3] @ PROBE_TIP_MM + halfway[:3, 3], point + (5, 13, -1500), atol=1e-9)
    probe.pivot(point)
    np.testing.assert_allclose(probe.poses(1.7)[probe.probe_rom], reference_to_tracker @ pivot_pose(1.7, point))


# -- the command line's bad input: one line, exit code 2 -------------------------------------------------------------
@needs_slicer
@pytest.mark.parametrize(
    "arguments, expected",
    [
        (["--tracker", "localhost"], "--tracker 'localhost': give HOST:PORT"),
        (["--tracker", "127.0.0.1:99999"], "give HOST:PORT"),
        (["--scene", "{tmp}/missing.mrb"], "missing.mrb: no such file"),
        (["--scene", "{tmp}"], "is a folder"),
        (["--scene", "{tmp}/notes.txt"], "give a Slicer scene, .mrb or .mrml"),
        (["--output", "{tmp}/notes.txt"], "--output"),
        (["--port", "70000"], "--port 70000"),
    ],
)
def test_bad_web_arguments_are_one_line_and_exit_code_2(tmp_path, capsys, arguments, expected):
    from RAMSICPRegistrationLib.commands import main

    (tmp_path / "notes.txt").write_text("not a scene")
    arguments = [argument.replace("{tmp}", str(tmp_path)) for argument in arguments]
    assert main(["web", "--port", "0", "--output", str(tmp_path / "out"), *arguments]) == 2
    error = capsys.readouterr().err.strip()
    assert expected in error and error.startswith("ramsicp web: error:") and "\n" not in error, error


@needs_slicer
def test_a_busy_port_is_reported_before_anything_starts(tmp_path, capsys):
    from RAMSICPRegistrationLib.commands import main

    with socket.create_server(("127.0.0.1", 0)) as busy:
        port = busy.getsockname()[1]
        assert main(["web", "--port", str(port), "--output", str(tmp_path)]) == 2
    error = capsys.readouterr().err.strip()
    assert f"cannot serve the page on 127.0.0.1:{port}" in error and "choose another --port" in error


@needs_slicer
def test_demo_and_scene_exclude_each_other():
    from RAMSICPRegistrationLib.commands import main

    assert main(["web", "--demo", "--scene", "x.mrb"]) == 2  # argparse's one line, its exit code returned


# -- MRML: the controller's additions, the display nodes, scene files ------------------------------------------------
@pytest.fixture
def scene():
    slicer = pytest.importorskip("slicer") if sys.version_info < (3, 10) else __import__("slicer")
    return slicer.vtkMRMLScene()


@needs_slicer
def test_the_controller_reports_each_pose_and_the_tip_in_world_and_reference_coordinates(scene):
    from RAMSICPRegistrationLib.navigation.controller import NavigationController

    controller = NavigationController(scene)
    try:
        check_pose_events_and_tip(controller, scene)
    finally:
        controller.close()  # no observer may outlive the test: a collected scene would call into it


def check_pose_events_and_tip(controller, scene):
    from RAMSICPRegistrationLib.core.transforms import make_transform, rotation_about_axis
    from RAMSICPRegistrationLib.navigation.navigation import set_matrix

    events = []
    controller.add_listener(lambda event, data: events.append((event, data)))
    probe = controller.steps.transform_node("ProbeToReference")
    controller.parameters.probeToReference = probe
    probe_pose = make_transform(rotation_about_axis((0.0, 0.0, 1.0), np.pi / 2), (10.0, 20.0, 30.0))
    set_matrix(probe, probe_pose)
    set_matrix(probe, probe_pose)
    assert events.count(("pose", "ProbeToReference")) == 2, "every tracker update is a pose, even the same one"
    assert controller.tip_position() is None and controller.status().tip_reference_mm is None  # no pivot yet
    tip = controller.steps.transform_node("ProbeTipToProbe")
    set_matrix(tip, make_transform(np.eye(3), (0.0, 0.0, -100.0)))
    tip.SetAndObserveTransformNodeID(probe.GetID())
    controller.parameters.probeTipToProbe = tip
    reference_to_image = controller.steps.transform_node("ReferenceToImage")
    set_matrix(reference_to_image, make_transform(np.eye(3), (1.0, 2.0, 3.0)))
    probe.SetAndObserveTransformNodeID(reference_to_image.GetID())
    set_matrix(probe, probe_pose)
    # The tip (0, 0, -100) in the probe, turned 90 degrees about z (z stays), moved by (10, 20, 30): (10, 20, -70).
    np.testing.assert_allclose(controller.status().tip_reference_mm, (10.0, 20.0, -70.0), atol=1e-9)
    np.testing.assert_allclose(controller.tip_position(), (11.0, 22.0, -67.0), atol=1e-9)  # + ReferenceToImage


def residual_table(scene, rows):
    """A residual table as ``NavigationLogic.register`` writes it: (label, x, y, z, residual, include) rows."""
    from vtkmodules.vtkCommonCore import vtkBitArray, vtkDoubleArray, vtkStringArray
    from vtkmodules.vtkCommonDataModel import vtkTable

    table = vtkTable()
    columns = [vtkStringArray()] + [vtkDoubleArray() for _ in range(4)] + [vtkBitArray()]
    for array, name in zip(columns, ("point", "x", "y", "z", "residual_mm", "include")):
        array.SetName(name)
        table.AddColumn(array)
    table.SetNumberOfRows(len(rows))
    for index, row in enumerate(rows):
        for column, value in enumerate(row):
            columns[column].SetValue(index, value)
    node = scene.AddNewNodeByClass("vtkMRMLTableNode", "RegistrationResiduals")
    node.SetAndObserveTable(table)
    return node


@needs_slicer
def test_residual_spheres_and_rows_follow_the_table(scene):
    from RAMSICPRegistrationLib.web.panel_state import residual_rows
    from RAMSICPRegistrationLib.web.scene_display import RESIDUAL_SPHERE_RADIUS_MM, update_residual_points

    table = residual_table(
        scene,
        [("P1", 0.0, 0.0, 0.0, 0.25, 1), ("P2", 50.0, 0.0, 0.0, float("nan"), 0), ("P3", 0.0, 80.0, 0.0, 0.75, 1)],
    )
    assert residual_rows(table) == [
        {"index": 0, "label": "P1", "residual": "0.25", "include": True, "note": ""},
        {"index": 1, "label": "P2", "residual": "", "include": False, "note": ""},
        {"index": 2, "label": "P3", "residual": "0.75", "include": True, "note": ""},
    ]
    registration = scene.AddNewNodeByClass("vtkMRMLLinearTransformNode", "ReferenceToImage")
    model = update_residual_points(scene, table, registration)
    from vtkmodules.util.numpy_support import vtk_to_numpy

    data = model.GetPolyData()
    points = vtk_to_numpy(data.GetPoints().GetData())
    residuals = vtk_to_numpy(data.GetPointData().GetArray("residual_mm"))
    radius = RESIDUAL_SPHERE_RADIUS_MM + 1e-4  # float32 points
    first = np.linalg.norm(points, axis=1) <= radius  # the sphere about P1
    third = np.linalg.norm(points - (0.0, 80.0, 0.0), axis=1) <= radius
    assert int(first.sum()) + int(third.sum()) == len(points), "only the included points P1 and P3 get a sphere"
    assert set(residuals[first]) == {0.25} and set(residuals[~first]) == {0.75}
    assert model.GetParentTransformNode() is registration
    assert update_residual_points(scene, table, registration) is model, "drawn again into the same node"


@needs_slicer
def test_the_needle_runs_from_the_tip_back_to_the_probe_origin_and_moves_only_when_the_tip_does(scene):
    from vtkmodules.vtkCommonCore import vtkCommand

    from RAMSICPRegistrationLib.navigation.navigation import matrix_of, set_matrix
    from RAMSICPRegistrationLib.web.scene_display import NEEDLE_RADIUS_MM, TIP_RADIUS_MM, move_needle, update_needle

    probe = scene.AddNewNodeByClass("vtkMRMLLinearTransformNode", "ProbeToReference")
    tip = scene.AddNewNodeByClass("vtkMRMLLinearTransformNode", "ProbeTipToProbe")
    tip.SetAndObserveTransformNodeID(probe.GetID())
    offset = np.eye(4)
    offset[:3, 3] = (0.0, 0.0, -110.0)
    set_matrix(tip, offset)
    needle = update_needle(scene, tip)
    bounds = np.array(needle.GetPolyData().GetBounds())  # x min, x max, y min, y max, z min, z max
    np.testing.assert_allclose(bounds[4:], (-TIP_RADIUS_MM, 110.0), atol=1e-6)  # tip ball at 0, shaft up to 110
    assert bounds[1] <= max(TIP_RADIUS_MM, NEEDLE_RADIUS_MM) + 1e-6
    pose_node = needle.GetParentTransformNode()
    np.testing.assert_allclose(matrix_of(pose_node), offset)  # the tip's pose in the world
    changes = []
    pose_node.AddObserver(vtkCommand.ModifiedEvent, lambda *_: changes.append(1))
    pose_node.AddObserver(pose_node.TransformModifiedEvent, lambda *_: changes.append(1))
    probe_pose = np.eye(4)
    probe_pose[:3, 3] = (5.0, 0.0, 0.0)
    set_matrix(probe, probe_pose)
    assert move_needle(scene, tip) and changes, "a 5 mm move moves the needle"
    np.testing.assert_allclose(matrix_of(pose_node), probe_pose @ offset)
    changes.clear()
    set_matrix(probe, probe_pose)  # the tracker repeats the pose: the views have nothing new to draw
    probe_pose[0, 3] += 0.005
    set_matrix(probe, probe_pose)  # 5 micrometres: the same picture
    assert not move_needle(scene, tip) and not move_needle(scene, tip) and not changes
    update_needle(scene, None)
    assert scene.GetNodeByID(needle.GetID()) is None


@needs_slicer
def test_a_scene_saved_by_the_controller_opens_as_mrml_and_as_mrb_and_a_broken_one_is_one_message(tmp_path):
    from RAMSICPRegistrationLib.navigation import mrml_nodes
    from RAMSICPRegistrationLib.navigation.controller import NavigationController
    from RAMSICPRegistrationLib.web.app import NavigationWebApp

    source = headless_scene()
    controller = NavigationController(source)
    controller.parameters.markersImage = mrml_nodes.fiducial_node(source, [[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]])
    written = controller.save(tmp_path / "saved" / "navigation.mrml")
    controller.close()
    archive = tmp_path / "saved.mrb"
    with zipfile.ZipFile(archive, "w") as mrb:
        for path in written:
            mrb.write(path, f"saved/{path.name}")
    for path in (written[0], archive):
        app = NavigationWebApp(tmp_path / "out")
        app.load_scene(path)
        app.start_workflow()
        np.testing.assert_allclose(
            mrml_nodes.fiducial_positions(app.controller.parameters.markersImage), [[1, 2, 3], [4, 5, 6]]
        )
        app.close()
    broken = tmp_path / "broken.mrb"
    broken.write_bytes(b"PK\x03\x04 truncated")
    with pytest.raises(ValueError, match="broken.mrb: cannot read it"):
        NavigationWebApp(tmp_path / "out").load_scene(broken)


@needs_slicer
def test_the_views_render_when_the_needle_moves_not_when_a_tracker_transform_updates(tmp_path):
    from RAMSICPRegistrationLib.navigation.navigation import set_matrix
    from RAMSICPRegistrationLib.web.app import NavigationWebApp
    from RAMSICPRegistrationLib.web.scene_display import update_needle

    app = NavigationWebApp(tmp_path)
    app.start_workflow()
    requests = {}
    for view in app.slicer.view_manager.get_views():  # a displayable manager asks its view to render
        tag = view.get_singleton_tag()
        requests[tag] = 0
        view._displayable_manager_group.AddObserver(
            "UpdateEvent", lambda *_, tag=tag: requests.update({tag: requests[tag] + 1})
        )
    steps, pose = app.controller.steps, np.eye(4)
    tip = steps.transform_node("ProbeTipToProbe")
    pose[:3, 3] = (0.0, 0.0, -110.0)
    set_matrix(tip, pose)
    update_needle(app.scene, tip)  # the needle, at the tip's pose (not under the streamed transforms)
    names = ("ProbeToTracker", "ReferenceToTracker", "ProbeToReference")
    for name in names:  # the first update (a node's first matrix) may ask for one render of the 3D view
        set_matrix(steps.transform_node(name), np.eye(4))
    requests.update({tag: 0 for tag in requests})
    for name in names:
        for _ in range(20):  # a still probe: the tracker streams the same poses
            set_matrix(steps.transform_node(name), np.eye(4))
    assert sum(requests.values()) == 0, f"views asked to render for invisible transforms: {requests}"
    pose[:3, 3] = (30.0, 0.0, -110.0)
    set_matrix(tip, pose)
    from RAMSICPRegistrationLib.web.scene_display import move_needle

    assert move_needle(app.scene, tip)
    assert all(count >= 1 for count in requests.values()), f"the moved needle must be drawn in every view: {requests}"
    app.close()


def test_the_guidance_shows_the_tools_distance_and_angle_and_whether_it_is_on_plan():
    from RAMSICPRegistrationLib.core.guidance import CutGuidance
    from RAMSICPRegistrationLib.navigation.controller import NavigationStatus, ToolState
    from RAMSICPRegistrationLib.web.panel_state import guidance_state

    def status(guidance):
        return NavigationStatus(
            tools=(ToolState("ProbeToReference", "valid", 0.0),),
            pivot_recording=False,
            pivot_poses=0,
            auto_collect=False,
            hold_still_collect=False,
            holding=False,
            probe_poses=0,
            probe_points=0,
            marker_points=0,
            guidance=guidance,
            cut="1 cut planned",
        )

    off = CutGuidance(0, 1, -1.04, 1.3, 5.0, 0.0, 10.0, 22.5, True, False)  # 1 mm below the plane, 5 degrees
    shown = guidance_state(status(off))
    assert shown["guidance"]["distance"] == "-1.0" and shown["guidance"]["angle"] == "5.0"
    assert not shown["guidance"]["on_plan"] and shown["guidance"]["text"].endswith("OFF PLAN")
    on = CutGuidance(0, 1, -0.04, 0.1, 0.5, 0.0, 10.0, 22.5, True, True)
    assert guidance_state(status(on))["guidance"]["distance"] == "+0.0"  # signed, but never "-0.0"
    assert guidance_state(status(on))["guidance"]["on_plan"] and guidance_state(status(None))["guidance"] is None


# -- the 3D view's display copy of the IPC, and the slices on the CT's voxel planes --------------------------------
def sphere_surface(radius_mm, resolution):
    """A closed triangulated sphere about the origin (vtkPolyData, mm) with about 2 x resolution^2 triangles, every
    vertex on the sphere."""
    from vtkmodules.vtkFiltersSources import vtkSphereSource

    source = vtkSphereSource()
    source.SetRadius(radius_mm)
    source.SetThetaResolution(resolution)
    source.SetPhiResolution(resolution)
    source.Update()
    return source.GetOutput()


def ipc_model(scene, surface):
    model = scene.AddNewNodeByClass("vtkMRMLModelNode", "IPC")
    model.SetAndObservePolyData(surface)
    model.CreateDefaultDisplayNodes()
    return model


@needs_slicer
def test_surface_deviation_is_the_distance_between_two_parallel_planes_and_two_concentric_spheres():
    from vtkmodules.vtkCommonTransforms import vtkTransform
    from vtkmodules.vtkFiltersCore import vtkTriangleFilter
    from vtkmodules.vtkFiltersGeneral import vtkTransformPolyDataFilter
    from vtkmodules.vtkFiltersSources import vtkPlaneSource

    from RAMSICPRegistrationLib.web.scene_display import surface_deviation_mm

    plane = vtkPlaneSource()
    plane.SetOrigin(0.0, 0.0, 0.0)
    plane.SetPoint1(40.0, 0.0, 0.0)
    plane.SetPoint2(0.0, 40.0, 0.0)
    plane.SetResolution(40, 40)
    triangles = vtkTriangleFilter()
    triangles.SetInputConnection(plane.GetOutputPort())
    triangles.Update()
    shift = vtkTransform()
    shift.Translate(0.0, 0.0, 0.3)
    shifted = vtkTransformPolyDataFilter()
    shifted.SetInputData(triangles.GetOutput())
    shifted.SetTransform(shift)
    shifted.Update()
    assert surface_deviation_mm(shifted.GetOutput(), triangles.GetOutput()) == pytest.approx(0.3, abs=1e-6)
    # Spheres of 30 and 30.25 mm, 0.25 mm apart; their flat triangles (edges of 0.75 mm) sag by 0.002 mm at most.
    assert surface_deviation_mm(sphere_surface(30.25, 250), sphere_surface(30.0, 250)) == pytest.approx(0.25, abs=0.005)


@needs_slicer
def test_the_3d_view_draws_a_tenth_of_the_ipc_within_tolerance_and_the_ipc_itself_when_a_copy_would_be_coarse(scene):
    from vtkmodules.util.numpy_support import vtk_to_numpy

    from RAMSICPRegistrationLib.web.scene_display import BONE_DISPLAY_TOLERANCE_MM, update_bone_display

    surface = sphere_surface(30.0, 250)  # 124,000 triangles, edges of 0.75 mm: as dense as an IPC
    model = ipc_model(scene, surface)
    copy = update_bone_display(scene, model)
    assert copy is not None and copy.GetDisplayNode().GetVisibility()
    assert not model.GetDisplayNode().GetVisibility3D(), "the IPC is drawn once, by its copy"
    assert copy.GetPolyData().GetNumberOfCells() <= 0.11 * surface.GetNumberOfCells()
    radii = np.linalg.norm(vtk_to_numpy(copy.GetPolyData().GetPoints().GetData()), axis=1)
    assert np.abs(radii - 30.0).max() < BONE_DISPLAY_TOLERANCE_MM, "every vertex drawn lies on the bone's surface"
    assert update_bone_display(scene, model) is copy and copy.GetPolyData() is not None, "made once, not again"

    coarse = ipc_model(scene, sphere_surface(30.0, 12))  # 240 triangles: a tenth of them is a rough polyhedron
    assert update_bone_display(scene, coarse) is None
    assert coarse.GetDisplayNode().GetVisibility3D(), "a copy beyond the tolerance is not drawn: the IPC is"
    assert model.GetDisplayNode().GetVisibility3D(), "the IPC the copy was made from is shown again"
    assert update_bone_display(scene, None) is None
    assert scene.GetFirstNodeByName("BoneDisplay") is None


@needs_slicer
def test_a_saved_scene_holds_the_ipc_shown_in_3d_and_no_display_node_of_the_browser_view(tmp_path):
    from RAMSICPRegistrationLib.web.app import NavigationWebApp
    from RAMSICPRegistrationLib.web.scene_display import DISPLAY_ATTRIBUTE, bone_as_saved, style_workflow_nodes

    app = NavigationWebApp(tmp_path)
    app.start_workflow()
    try:
        parameters = app.controller.parameters
        model = ipc_model(app.scene, sphere_surface(30.0, 250))
        parameters.ipcModel = model
        style_workflow_nodes(parameters)
        copy = app.scene.GetFirstNodeByName("BoneDisplay")
        assert copy is not None and not model.GetDisplayNode().GetVisibility3D()
        with bone_as_saved(app.scene):
            assert model.GetDisplayNode().GetVisibility3D(), "while the scene is written, the IPC is shown"
        assert not model.GetDisplayNode().GetVisibility3D()
        path = tmp_path / "saved" / "navigation.mrml"
        app.run("save", path)
        assert not model.GetDisplayNode().GetVisibility3D() and copy.GetDisplayNode().GetVisibility()
    finally:
        app.close()
    text = path.read_text()
    assert DISPLAY_ATTRIBUTE not in text and "BoneDisplay" not in text, "the view's own nodes are never saved"
    assert [file.name for file in path.parent.glob("*.vtk")] == [f"IPC-{model.GetID()}.vtk"], "one model: the IPC"
    archive = tmp_path / "saved.mrb"
    with zipfile.ZipFile(archive, "w") as mrb:
        for file in path.parent.iterdir():
            mrb.write(file, f"saved/{file.name}")
    reader = NavigationWebApp(tmp_path / "out")
    reader.load_scene(archive)  # as Slicer opens it: before this view styles anything
    loaded = reader.scene.GetFirstNodeByName("IPC")
    assert loaded.GetPolyData().GetNumberOfCells() == model.GetPolyData().GetNumberOfCells()
    assert loaded.GetDisplayNode().GetVisibility() and loaded.GetDisplayNode().GetVisibility3D(), "Slicer shows it"
    assert reader.scene.GetFirstNodeByName("BoneDisplay") is None
    nodes = [reader.scene.GetNthNode(index) for index in range(reader.scene.GetNumberOfNodes())]
    assert not [node.GetName() for node in nodes if node.GetAttribute(DISPLAY_ATTRIBUTE) is not None]
    reader.close()


def slice_node(scene, name, normal_column):
    """A slice node whose plane is normal to RAS axis ``normal_column`` (0 R, 1 A, 2 S), at the origin."""
    import slicer

    node = slicer.vtkMRMLSliceNode()
    node.SetName(name)
    node.SetLayoutName(name)
    scene.AddNode(node)
    in_plane = [axis for axis in range(3) if axis != normal_column]
    slice_to_ras = node.GetSliceToRAS()
    for column, axis in enumerate([*in_plane, normal_column]):
        for row in range(3):
            slice_to_ras.SetElement(row, column, 1.0 if row == axis else 0.0)
        slice_to_ras.SetElement(axis, 3, 0.0)
    node.UpdateMatrices()
    return node


def slice_origins(nodes):
    return np.array([[node.GetSliceToRAS().GetElement(row, 3) for row in range(3)] for node in nodes])


@needs_slicer
def test_the_slices_follow_the_tip_on_the_cts_voxel_planes_and_stay_while_it_moves_within_a_voxel(scene):
    from vtkmodules.vtkCommonCore import vtkCommand

    from RAMSICPRegistrationLib.web.scene_display import follow_tip

    sagittal, coronal, axial = (slice_node(scene, name, axis) for axis, name in enumerate(("S", "C", "A")))
    ct = scene.AddNewNodeByClass("vtkMRMLScalarVolumeNode", "CT")
    ct.SetSpacing(0.5, 0.8, 1.25)  # voxel centres at R = 10 + 0.5 i, A = 20 + 0.8 j, S = 30 + 1.25 k
    ct.SetOrigin(10.0, 20.0, 30.0)
    assert follow_tip(scene, (10.3, 20.5, 31.0), ct) == 3
    # i = 0.6 -> 1, j = 0.625 -> 1, k = 0.8 -> 1: R 10.5 (sagittal), A 20.8 (coronal), S 31.25 (axial).
    origins = slice_origins((sagittal, coronal, axial))
    np.testing.assert_allclose([origins[0, 0], origins[1, 1], origins[2, 2]], (10.5, 20.8, 31.25), atol=1e-9)
    changes = []
    for node in (sagittal, coronal, axial):
        node.AddObserver(vtkCommand.ModifiedEvent, lambda *_: changes.append(1))
    assert follow_tip(scene, (10.45, 20.9, 31.5), ct) == 0, "i 0.9, j 1.125, k 1.2: the same voxel planes"
    assert not changes, "a slice that stays is not cut again"
    assert follow_tip(scene, (10.8, 20.9, 31.5), ct) == 1  # i = 1.6 -> 2: only the sagittal slice moves
    assert sagittal.GetSliceToRAS().GetElement(0, 3) == pytest.approx(11.0, abs=1e-9)
    transform = scene.AddNewNodeByClass("vtkMRMLLinearTransformNode", "CTMoved")
    ct.SetAndObserveTransformNodeID(transform.GetID())
    follow_tip(scene, (10.3, 20.5, 31.0), ct)  # a CT under a transform: exactly through the tip
    np.testing.assert_allclose(np.diag(slice_origins((sagittal, coronal, axial))), (10.3, 20.5, 31.0), atol=1e-9)


# -- the server log ------------------------------------------------------------------------------------------------
@needs_slicer
def test_only_the_known_vtk_deprecation_warning_is_kept_out_of_the_log(capfd, caplog):
    """VTK 9.6 warns when a WindowResizeEvent observer is added to an interactor (trame-slicer's slice views do):
    within ``views_created_quietly`` that warning, and no other, is dropped; afterwards VTK reports as usual."""
    import vtkmodules.vtkInteractionStyle  # noqa: F401 (the interactor's default style)
    import vtkmodules.vtkRenderingOpenGL2  # noqa: F401 (the platform's interactor class)
    from trame_slicer.views import abstract_view
    from vtkmodules.vtkCommonCore import vtkCommand

    from RAMSICPRegistrationLib.web.vtk_warnings import KNOWN_WARNING, views_created_quietly

    original = abstract_view.vtkRenderWindowInteractor
    bare = original()
    bare.AddObserver(vtkCommand.WindowResizeEvent, lambda caller, event: None)
    assert KNOWN_WARNING in capfd.readouterr().err  # the warning this is about, as VTK prints it
    with caplog.at_level("WARNING"), views_created_quietly() as watched:
        interactor = abstract_view.vtkRenderWindowInteractor()  # as trame-slicer's views create theirs
        interactor.AddObserver(vtkCommand.WindowResizeEvent, lambda caller, event: None)
        interactor.InvokeEvent(vtkCommand.WarningEvent, "another warning")
    err = capfd.readouterr().err
    assert KNOWN_WARNING not in err and KNOWN_WARNING not in caplog.text
    assert [record.getMessage() for record in caplog.records] == ["VTK: another warning"]
    assert [created for created, _ in watched] == [interactor] and interactor.IsA("vtkRenderWindowInteractor")
    assert abstract_view.vtkRenderWindowInteractor is original and not interactor.HasObserver(vtkCommand.WarningEvent)
    interactor.AddObserver(vtkCommand.WindowResizeEvent, lambda caller, event: None)
    assert KNOWN_WARNING in capfd.readouterr().err  # after the views exist, warnings are VTK's again


@needs_slicer
def test_the_display_copy_is_read_back_from_the_cache_as_it_was_made(tmp_path, caplog):
    """The IPC's display copy is made once per IPC (``ramsicp web --demo`` shows the same one at every start): read
    back, its vertices, triangles, normals and deviation are those made; a damaged file is made again."""
    from vtkmodules.util.numpy_support import vtk_to_numpy

    from RAMSICPRegistrationLib.io.vtk_arrays import triangle_arrays
    from RAMSICPRegistrationLib.web.scene_display import bone_display_surface, cached_display_copy, surface_deviation_mm

    surface = sphere_surface(30.0, 120)
    made, deviation = cached_display_copy(surface, directory=tmp_path)
    direct = bone_display_surface(surface)
    assert deviation == surface_deviation_mm(direct, surface)
    (path,) = tmp_path.glob("display-copy-*.npz")
    read, read_deviation = cached_display_copy(surface, directory=tmp_path)
    assert read is not made and read_deviation == deviation
    for mesh in (made, read):
        for mine, theirs in zip(triangle_arrays(mesh), triangle_arrays(direct)):
            np.testing.assert_array_equal(mine, theirs)
        normals = vtk_to_numpy(mesh.GetPointData().GetNormals())
        np.testing.assert_array_equal(normals, vtk_to_numpy(direct.GetPointData().GetNormals()))
    other, _ = cached_display_copy(sphere_surface(30.0, 60), directory=tmp_path)  # another IPC, another copy
    assert len(list(tmp_path.glob("display-copy-*.npz"))) == 2
    path.write_bytes(path.read_bytes()[:1000])  # cut short
    with caplog.at_level("WARNING"):
        again, again_deviation = cached_display_copy(surface, directory=tmp_path)
    assert "is damaged" in caplog.text and again_deviation == deviation
    np.testing.assert_array_equal(triangle_arrays(again)[1], triangle_arrays(direct)[1])
