"""The arm of the cell: a UR5e, its files, published kinematics and limits.

Numbers and their sources are in ``models/ur5e/README.md``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from algorithms.geometry.kinematics import DHTable

MODELS_DIR = Path(__file__).resolve().parent.parent / "models"
UR5E_DIR = MODELS_DIR / "ur5e"
SCENE_XML = UR5E_DIR / "scene.xml"

UR5E_DH = DHTable(
    a=(0.0, -0.425, -0.3922, 0.0, 0.0, 0.0),
    d=(0.1625, 0.0, 0.0, 0.1333, 0.0997, 0.0996),
    alpha=(np.pi / 2, 0.0, 0.0, np.pi / 2, -np.pi / 2, 0.0),
)
JOINT_NAMES = (
    "shoulder_pan_joint",
    "shoulder_lift_joint",
    "elbow_joint",
    "wrist_1_joint",
    "wrist_2_joint",
    "wrist_3_joint",
)
LINK_BODIES = (
    "shoulder_pan_link",
    "shoulder_lift_link",
    "elbow_link",
    "wrist_1_link",
    "wrist_2_link",
    "wrist_3_link",
)
FLANGE_BODY = "wrist_3_link"
FLANGE_SITE = "flange"
VELOCITY_LIMIT_RAD_S = np.full(6, np.pi)  # 180 deg/s on every joint (UR5e datasheet)
ACCELERATION_LIMIT_RAD_S2 = np.full(6, 2.0 * np.pi)  # planning limit chosen for smooth servo tracking
# Elbow up, wrist pointing down, flange over the table at +x in front of the base.
HOME_Q = np.array([np.pi, -1.9, 1.9, -1.5707963267948966, -1.5707963267948966, 0.0])

# Geom groups of the cell: 1 arm and what it carries, 2 table and fixture, 3 workpiece.
GROUP_ARM, GROUP_FIXTURE, GROUP_WORKPIECE = 1, 2, 3
# Geom groups a static ray (laser occlusion check) may hit: fixture and workpiece.
STATIC_GROUPS = np.array([0, 0, 1, 1, 0, 0], dtype=np.uint8)
# Geom groups the scan planner casts at: the workpiece only.
WORKPIECE_GROUPS = np.array([0, 0, 0, 1, 0, 0], dtype=np.uint8)
# The flange frame (DH frame 6) in the wrist_3 body: d6 along its z.
T_WRIST3_FLANGE = np.eye(4)
T_WRIST3_FLANGE[2, 3] = UR5E_DH.d[5]
