"""Rotation vectors <-> matrices (resection.camera.rotation) against SciPy and OpenCV."""

from __future__ import annotations

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from resection.camera.rotation import (
    euler_zyx,
    matrix_to_rotvec,
    rotvec_to_matrix,
    rotvecs_to_matrices,
)


def _rotvecs():
    rng = np.random.default_rng(3)
    axes = rng.normal(size=(200, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    angles = np.concatenate([rng.uniform(0, np.pi, 150),
                             [0.0, 1e-14, 1e-9, 1e-6, 1e-4, 9.9e-5, 1e-3, 0.999e-3, 0.1,
                              np.pi / 2, np.pi - 1e-3, np.pi - 1e-7, np.pi - 1e-12, np.pi],
                             rng.uniform(3.0, np.pi, 36)])
    return axes * angles[:, None]


def test_matrix_of_a_rotation_vector_is_scipys_and_opencvs():
    for rv in _rotvecs():
        R = rotvec_to_matrix(rv)
        np.testing.assert_allclose(R, Rotation.from_rotvec(rv).as_matrix(), rtol=0,
                                   atol=1e-14)
        np.testing.assert_allclose(R, cv2.Rodrigues(rv)[0], rtol=0, atol=1e-12)


def test_rotation_vector_of_a_matrix_is_scipys():
    """The same vector, angle in [0, pi]; near pi (within 1e-6 rad) v and -v are nearly
    the same rotation: compared as matrices there."""
    for rv in _rotvecs():
        R = Rotation.from_rotvec(rv).as_matrix()
        got = matrix_to_rotvec(R)
        ref = Rotation.from_matrix(R).as_rotvec()
        assert np.linalg.norm(got) <= np.pi + 1e-12
        if np.pi - np.linalg.norm(ref) > 1e-6:
            np.testing.assert_allclose(got, ref, rtol=0, atol=1e-13)
        np.testing.assert_allclose(Rotation.from_rotvec(got).as_matrix(), R, rtol=0,
                                   atol=1e-13)


def test_round_trip_and_opencv_on_a_camera_like_pose():
    rv = np.array([0.3, -2.1, 0.45])
    R = cv2.Rodrigues(rv)[0]
    np.testing.assert_allclose(matrix_to_rotvec(R), cv2.Rodrigues(R)[0].ravel(), atol=1e-12)
    np.testing.assert_allclose(rotvec_to_matrix(matrix_to_rotvec(R)), R, atol=1e-15)


def test_matrices_of_many_rotation_vectors_at_once_are_scipys():
    rv = _rotvecs()
    M = rotvecs_to_matrices(rv)
    assert M.shape == (len(rv), 3, 3)
    np.testing.assert_allclose(M, Rotation.from_rotvec(rv).as_matrix(), rtol=0, atol=1e-14)
    assert rotvecs_to_matrices(np.zeros((0, 3))).shape == (0, 3, 3)


def test_yaw_pitch_roll_are_scipys_zyx_euler_angles():
    M = Rotation.from_rotvec(_rotvecs()).as_matrix()
    np.testing.assert_allclose(euler_zyx(M), Rotation.from_matrix(M).as_euler("ZYX"),
                               rtol=0, atol=1e-12)
    # M = Rz(yaw) Ry(pitch) Rx(roll), written out
    y, p, r = 0.4, -0.3, 1.1
    Rz = np.array([[np.cos(y), -np.sin(y), 0], [np.sin(y), np.cos(y), 0], [0, 0, 1]])
    Ry = np.array([[np.cos(p), 0, np.sin(p)], [0, 1, 0], [-np.sin(p), 0, np.cos(p)]])
    Rx = np.array([[1, 0, 0], [0, np.cos(r), -np.sin(r)], [0, np.sin(r), np.cos(r)]])
    np.testing.assert_allclose(euler_zyx((Rz @ Ry @ Rx)[None])[0], [y, p, r], atol=1e-15)
    # gimbal lock (pitch +-90 deg): roll 0 and the yaw that rebuilds the matrix
    for pitch in (np.pi / 2, -np.pi / 2):
        R = Rotation.from_euler("ZYX", [0.3, pitch, 0.2]).as_matrix()
        got = euler_zyx(R[None])[0]
        assert got[2] == 0.0 and abs(got[1] - pitch) < 1e-12
        np.testing.assert_allclose(Rotation.from_euler("ZYX", got).as_matrix(), R,
                                   atol=1e-12)
