"""The reward context: named batched arrays that reward functions, predicates and observations read.

``CONTEXT_DOC`` is included verbatim in the reward-generator prompt, so it is written for a reader
who sees nothing else: every key, shape, unit and frame.
"""

from __future__ import annotations

import numpy as np

from itskill.sim.controller import ControllerConfig

MAX_OBJECTS = 2
MAX_FIXTURES = 2

_YAW_LOW, _YAW_HIGH = ControllerConfig().yaw_limits

CONTEXT_DOC = f"""\
Reward context `ctx`: a dict of NumPy arrays batched over N parallel environments.
Units are metres, radians and seconds; positions are in the world frame, whose origin is the robot
base on the table top (z = 0 is the table surface, +z is up). Every scene has 2 object slots and 2
fixture slots; an unused slot has mask 0 and zeros elsewhere. Object i is meant for fixture
`obj_fixture[i]` (a nut for its bolt, a peg for its hole).

Robot
  ee_pos          (N, 3)  grip point between the fingertip pads
  ee_vel          (N, 3)  grip point velocity, m/s
  ee_yaw          (N,)    hand yaw relative to its home orientation, within the wrist's range
                          [{_YAW_LOW:g}, {_YAW_HIGH:g}]; the hand always points down
  gripper_width   (N,)    distance between the fingers, 0 (closed) to 0.08 (open)
  grip_closed     (N,)    1.0 if the last action commanded the fingers closed
  action          (N, 5)  last action [dx, dy, dz, dyaw, grip] in [-1, 1]
Objects (movable parts: hex nuts, pegs)
  obj_mask        (N, 2)  1.0 for a real object
  obj_pos         (N, 2, 3) part centre
  obj_vel         (N, 2, 3) part centre velocity, m/s
  obj_yaw         (N, 2)  part yaw
  obj_tilt        (N, 2)  angle between the part axis and vertical (0 = upright)
  obj_height      (N, 2)  part height along its axis
  obj_width       (N, 2)  width the fingers close on (a nut's across-flats, a peg's thickness)
  obj_bottom_z    (N, 2)  height of the part's bottom face above the table
  obj_to_ee       (N, 2, 3) ee_pos - obj_pos
  grasped         (N, 2)  1.0 if the closed fingers hold the part (across its width, a
                          rectangular peg's longer side too, or across its height when it
                          has tipped over in the grip)
Fixtures (fixed to the table: bolts, holes)
  fix_mask        (N, 2)  1.0 for a real fixture
  fix_pos         (N, 2, 3) target point: a bolt's tip centre or a hole's entrance centre
  fix_yaw         (N, 2)  fixture yaw (a rectangular hole's long side is along its x axis)
  seat_z          (N, 2)  height a part rests at when fully home: the bolt head top, the hole bottom
  obj_fixture     (N, 2)  index of the fixture object i is meant for
  obj_to_fix      (N, 2, 3) fixture point minus the part's bottom centre, for object i's fixture
  yaw_error       (N, 2)  part yaw minus fixture yaw, wrapped to the part's symmetry (0 if round)
  engaged         (N, 2)  1.0 if the nut's thread is engaged on its bolt, or the peg is in its hole
  insertion_depth (N, 2)  how far the part's bottom is below the fixture point while engaged
                          (peg depth in the hole, nut travel down the bolt), else 0
  seat_gap        (N, 2)  part bottom minus the fixture's seat_z
  thread_lead     (N, 2)  how far an engaged nut moves along its bolt per radian it turns
                          (pitch / 2 pi; down when turned clockwise seen from above); 0 for a peg
Task
  stage           (N,)    index of the current subtask (0-based)
  n_stages        (N,)    number of subtasks
  time_frac       (N,)    elapsed fraction of the episode, 0 to 1
"""


def wrap_angle(angle: np.ndarray, period: float = 2 * np.pi) -> np.ndarray:
    """Wrap to [-period/2, period/2)."""
    return (angle + period / 2) % period - period / 2


def min_grasp_width(obj_width: np.ndarray, obj_height: np.ndarray) -> np.ndarray:
    """The smallest finger width at which the closed fingers still hold a part.

    The fingers may hold a part across its width or, tipped over in the grip, across its height
    (a nut on edge): either way it is held and comes along when the hand moves. Below this width
    the fingers have closed on nothing.
    """
    return np.minimum(obj_width, obj_height) - 0.004


def max_grip_offset(obj_height: np.ndarray | float) -> np.ndarray | float:
    """How far a part's centre may sit above or below the grip point and still count as held:
    half its height plus 6 mm, the fingers closed on its upper or lower edge."""
    return obj_height / 2 + 0.006


def quat_to_mat(quat: np.ndarray) -> np.ndarray:
    """Unit quaternions (..., 4) in MuJoCo's (w, x, y, z) order -> rotation matrices (..., 3, 3)."""
    w, x, y, z = np.moveaxis(quat, -1, 0)
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )
