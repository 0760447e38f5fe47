"""CT loading: NRRD and NIfTI geometry converted once to RAS, Slicer volume nodes, and bad volumes."""

import nibabel
import nrrd
import numpy as np
import pytest

from RAMSICPRegistrationLib.core.transforms import rotation_about_axis
from RAMSICPRegistrationLib.image.volume_io import CTVolume, check_volume, load_volume, save_nrrd
from RAMSICPRegistrationLib.io.point_files import PointFileError

VOXELS = np.arange(4 * 5 * 6, dtype=np.int16).reshape(4, 5, 6)


def _oblique_ijk_to_ras():
    matrix = np.eye(4)
    matrix[:3, :3] = rotation_about_axis((1.0, 2.0, 0.5), np.radians(25.0)) * np.array([0.5, 0.5, 0.625])
    matrix[:3, 3] = (-12.0, 40.0, 7.5)
    return matrix


def test_nrrd_in_lps_is_read_as_ras_by_hand(tmp_path):
    # Origin (10, 20, 30) LPS with axes L, P, S of 0.5, 0.5, 0.625 mm: voxel (2, 3, 4) is at
    # LPS (11, 21.5, 32.5), that is RAS (-11, -21.5, 32.5).
    header = {
        "space": "left-posterior-superior",
        "space directions": np.diag([0.5, 0.5, 0.625]),
        "space origin": np.array([10.0, 20.0, 30.0]),
    }
    nrrd.write(str(tmp_path / "ct.nrrd"), VOXELS, header, index_order="F")
    volume = load_volume(tmp_path / "ct.nrrd")
    np.testing.assert_allclose(volume.ijk_to_ras_points([[2, 3, 4]]), [[-11.0, -21.5, 32.5]])
    np.testing.assert_array_equal(volume.voxels, VOXELS)
    np.testing.assert_allclose(volume.spacing, [0.5, 0.5, 0.625])


def test_nrrd_in_ras_space(tmp_path):
    header = {
        "space": "right-anterior-superior",
        "space directions": np.diag([1.0, 2.0, 3.0]),
        "space origin": np.array([1.0, 2.0, 3.0]),
    }
    nrrd.write(str(tmp_path / "ras.nrrd"), VOXELS, header, index_order="F")
    np.testing.assert_allclose(load_volume(tmp_path / "ras.nrrd").ijk_to_ras_points([[1, 1, 1]]), [[2.0, 4.0, 6.0]])


def test_save_and_load_keep_an_oblique_geometry(tmp_path):
    volume = CTVolume(voxels=VOXELS, ijk_to_ras=_oblique_ijk_to_ras())
    save_nrrd(tmp_path / "oblique.nrrd", volume)
    loaded = load_volume(tmp_path / "oblique.nrrd")
    np.testing.assert_allclose(loaded.ijk_to_ras, volume.ijk_to_ras, atol=1e-12)
    np.testing.assert_array_equal(loaded.voxels, VOXELS)
    ras = np.array([[3.0, -7.0, 11.0]])
    np.testing.assert_allclose(loaded.ijk_to_ras_points(loaded.ras_to_ijk_points(ras)), ras)


@pytest.mark.parametrize("name", ["ct.nii", "ct.nii.gz"])
def test_nifti_affine_is_ras(tmp_path, name):
    affine = _oblique_ijk_to_ras()
    nibabel.save(nibabel.Nifti1Image(VOXELS, affine), str(tmp_path / name))
    volume = load_volume(tmp_path / name)
    np.testing.assert_allclose(volume.ijk_to_ras, affine, atol=1e-5)  # NIfTI stores float32
    np.testing.assert_array_equal(volume.voxels, VOXELS)


def test_the_shipped_real_ct_geometry():
    from pathlib import Path

    volume = load_volume(Path(__file__).parent / "Data" / "example_ct.nii.gz")
    assert volume.voxels.shape == (122, 101, 112)
    np.testing.assert_allclose(volume.spacing, 3.0)
    np.testing.assert_allclose(volume.ijk_to_ras_points([[0, 0, 0]]), [[-177.956, 11.319, 94.302]], atol=1e-3)


@pytest.mark.parametrize(
    "voxels, matrix, message",
    [
        (np.zeros((4, 5)), np.eye(4), "expected a 3-D volume, got 2 dimension(s)"),
        (np.zeros((4, 5, 6, 2)), np.eye(4), "expected a 3-D volume, got 4 dimension(s)"),
        (np.zeros((4, 1, 6)), np.eye(4), "is empty or flat"),
        (np.zeros((4, 5, 6)), np.diag([1.0, 0.0, 1.0, 1.0]), "voxel spacing [1.0, 0.0, 1.0] mm has a zero"),
        (np.zeros((4, 5, 6)), np.full((4, 4), np.nan), "must be a finite 4x4 matrix"),
    ],
)
def test_bad_volumes_say_what_to_change(voxels, matrix, message):
    with pytest.raises(ValueError) as error:
        check_volume(voxels, matrix)
    assert message in str(error.value)


def test_bad_volume_files_name_the_file(tmp_path):
    header = {
        "space": "left-posterior-superior",
        "space directions": np.diag([0.5, 0.0, 0.625]),
        "space origin": np.zeros(3),
    }
    nrrd.write(str(tmp_path / "zero.nrrd"), VOXELS, header, index_order="F")
    with pytest.raises(PointFileError, match="zero.nrrd: voxel spacing .* has a zero"):
        load_volume(tmp_path / "zero.nrrd")
    (tmp_path / "broken.nii.gz").write_bytes(b"not a nifti")
    with pytest.raises(PointFileError, match="broken.nii.gz: cannot read as a volume"):
        load_volume(tmp_path / "broken.nii.gz")
    with pytest.raises(PointFileError, match="unknown volume type"):
        load_volume(__file__)
    with pytest.raises(PointFileError, match="no such file"):
        load_volume(tmp_path / "missing.nrrd")


def test_slicer_volume_node_gives_the_same_volume():
    slicer = pytest.importorskip("slicer", reason="slicer-core needs Python >= 3.10")
    from vtkmodules.util.numpy_support import numpy_to_vtk
    from vtkmodules.vtkCommonDataModel import vtkImageData
    from vtkmodules.vtkCommonMath import vtkMatrix4x4

    scene = slicer.vtkMRMLScene()
    node = scene.AddNewNodeByClass("vtkMRMLScalarVolumeNode", "CT")
    image = vtkImageData()
    image.SetDimensions(*VOXELS.shape)
    image.GetPointData().SetScalars(numpy_to_vtk(VOXELS.transpose(2, 1, 0).ravel(), deep=True))
    node.SetAndObserveImageData(image)
    matrix = vtkMatrix4x4()
    oblique = _oblique_ijk_to_ras()
    for row in range(4):
        for column in range(4):
            matrix.SetElement(row, column, oblique[row, column])
    node.SetIJKToRASMatrix(matrix)
    volume = load_volume(node)
    np.testing.assert_array_equal(volume.voxels, VOXELS)
    np.testing.assert_allclose(volume.ijk_to_ras, oblique, atol=1e-12)
    with pytest.raises(TypeError, match="expected a vtkMRMLScalarVolumeNode"):
        load_volume(scene.AddNewNodeByClass("vtkMRMLLinearTransformNode"))


def _write_dicom_series(folder, voxels, ijk_to_lps, series_uid="1.2.3.4"):
    """A minimal CT series (one file a slice), as a scanner writes it: LPS positions, rescale to HU."""
    from pydicom.dataset import Dataset, FileMetaDataset
    from pydicom.uid import CTImageStorage, ExplicitVRLittleEndian, generate_uid

    folder.mkdir(exist_ok=True)
    spacing = np.linalg.norm(ijk_to_lps[:3, :3], axis=0)
    for k in range(voxels.shape[2]):
        meta = FileMetaDataset()
        meta.MediaStorageSOPClassUID = CTImageStorage
        meta.MediaStorageSOPInstanceUID = generate_uid()
        meta.TransferSyntaxUID = ExplicitVRLittleEndian
        dataset = Dataset()
        dataset.file_meta = meta
        dataset.SOPClassUID, dataset.SOPInstanceUID = CTImageStorage, meta.MediaStorageSOPInstanceUID
        dataset.SeriesInstanceUID = series_uid
        dataset.Modality = "CT"
        dataset.ImageOrientationPatient = [
            float(v) for v in np.concatenate((ijk_to_lps[:3, 0] / spacing[0], ijk_to_lps[:3, 1] / spacing[1]))
        ]
        dataset.ImagePositionPatient = [float(v) for v in ijk_to_lps[:3, 3] + k * ijk_to_lps[:3, 2]]
        dataset.PixelSpacing = [float(spacing[1]), float(spacing[0])]  # row spacing, column spacing
        dataset.Rows, dataset.Columns = voxels.shape[1], voxels.shape[0]
        dataset.SamplesPerPixel, dataset.PhotometricInterpretation = 1, "MONOCHROME2"
        dataset.BitsAllocated, dataset.BitsStored, dataset.HighBit, dataset.PixelRepresentation = 16, 16, 15, 0
        dataset.RescaleSlope, dataset.RescaleIntercept = 1, -1024
        dataset.PixelData = (voxels[:, :, k].T.astype(np.int32) + 1024).astype(np.uint16).tobytes()
        # Files named against the slice order: the reader must sort by position, not by name.
        name = f"{series_uid}-slice{voxels.shape[2] - k:03d}.dcm"
        try:
            dataset.save_as(str(folder / name), enforce_file_format=True)  # pydicom 3
        except TypeError:
            dataset.save_as(str(folder / name), write_like_original=False)  # pydicom 2 (Python 3.9)


def test_dicom_series_folder_is_read_with_its_oblique_geometry(tmp_path):
    ijk_to_lps = np.eye(4)
    ijk_to_lps[:3, :3] = rotation_about_axis((0.3, 0.2, 1.0), np.radians(15.0)) * np.array([0.5, 0.5, 0.625])
    ijk_to_lps[:3, 3] = (-60.0, 25.0, 100.0)
    hu = VOXELS.astype(np.int16) * 10 - 500
    _write_dicom_series(tmp_path / "series", hu, ijk_to_lps)
    volume = load_volume(tmp_path / "series")
    np.testing.assert_array_equal(volume.voxels, hu)
    np.testing.assert_allclose(volume.ijk_to_ras, np.diag([-1.0, -1.0, 1.0, 1.0]) @ ijk_to_lps, atol=1e-9)


def test_dicom_folders_that_are_not_one_series(tmp_path):
    (tmp_path / "empty").mkdir()
    (tmp_path / "empty" / "notes.txt").write_text("no images here")
    with pytest.raises(PointFileError, match="no DICOM image"):
        load_volume(tmp_path / "empty")
    ijk_to_lps = np.diag([0.5, 0.5, 1.0, 1.0])
    _write_dicom_series(tmp_path / "mixed", VOXELS[:, :, :2], ijk_to_lps, series_uid="1.1")
    _write_dicom_series(tmp_path / "mixed", VOXELS[:, :, :3], ijk_to_lps, series_uid="1.2")
    with pytest.raises(PointFileError, match="holds 2 DICOM series"):
        load_volume(tmp_path / "mixed")
