"""A laser tracker that measures the TRUE robot's flange during a co-simulation.

The paper measures the TCP with a Leica LTD600 laser tracker sampled every 1 ms
(section 2.3.3). The model: every ``period_s`` a periodic master task reads the
plant's joint states ``q`` (the ``rx130l_plant`` outputs ``q[1..6]`` at that instant),
evaluates the flange (``tool0``) position of the TRUE arm - the nominal URDF with the
true robot's 39 geometric errors folded in (``TrueRobot.kinematic_model()``) - and
adds Gaussian noise (independent per base-frame axis, seeded). The result goes to the
master variables ``tracker.x``, ``tracker.y``, ``tracker.z`` (m, base_link), which
the job's recorder samples in the same tick.

Joint-angle convention: the plant's ``q`` is the encoder-side joint angle, i.e. motor
angle / gear ratio as the drive's encoder sees it. The true kinematics take exactly
that angle: the encoder offsets are part of the geometric errors (``offset1..6``,
folded into the joint placements by ``robot.geometric_errors``), so the true flange
is ``f_DK,true(q_plant)``. (The plant's rigid-body dynamics use the nominal geometry:
the mm-level geometric errors change the dynamics negligibly.)

The tracker is registered to ``base_link`` (its own placement and registration
errors are not modelled); it always sees the reflector. The reflector sits at the flange
centre by default; ``TrackerConfig.reflector`` puts it elsewhere on the tool (m in
``tool0``), e.g. off the axis of joint 6 so that a rotation about that axis is seen
(the identification campaign's gear-stiffness measurement).

Each sample is one call of a small compiled function (``tracker_kernel.c``, built by
:mod:`native`): the same forward kinematics as pinocchio on the same model (to
round-off, tested), reading ``q`` from the master's bus and writing the noisy position
to the tracker variables; pinocchio's ``forwardKinematics`` through its Python binding
costs several times more per sample. Without a C compiler, or for a chain the kernel
does not cover, the task uses pinocchio (:meth:`LaserTracker.flange_position`).
"""
from __future__ import annotations

import ctypes
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pinocchio as pin

from native import load_library
from robot.description import FLANGE_FRAME

KERNEL_SOURCE = Path(__file__).with_name("tracker_kernel.c")
_AXIS_KINDS = {"JointModelRX": 0, "JointModelRY": 1, "JointModelRZ": 2, "JointModelRevoluteUnaligned": 3}


class _TrackerPlan(ctypes.Structure):
    """Mirror of ``tracker_plan`` in tracker_kernel.c."""

    _fields_ = [("R", (ctypes.c_double * 9) * 6), ("p", (ctypes.c_double * 3) * 6),
                ("axis", (ctypes.c_double * 3) * 6), ("kind", ctypes.c_longlong * 6),
                ("flange", ctypes.c_double * 3), ("q", ctypes.c_void_p), ("out", ctypes.c_void_p)]


def compiled_chain(model: pin.Model, frame_id: int, reflector=(0.0, 0.0, 0.0)) -> _TrackerPlan | None:
    """The kernel's description of ``model`` (six revolute joints in a serial chain, the
    frame on joint 6; the measured point ``reflector`` in m in that frame), or None when the
    model is not such a chain."""
    if model.nq != 6 or model.njoints != 7 or list(model.parents) != [0, 0, 1, 2, 3, 4, 5]:
        return None
    frame = model.frames[frame_id]
    if frame.parentJoint != 6:
        return None
    plan = _TrackerPlan()
    for j in range(1, 7):
        joint = model.joints[j]
        kind = _AXIS_KINDS.get(joint.shortname())
        if kind is None:
            return None
        axis = np.zeros(3)
        if kind == 3:
            axis = np.asarray(joint.extract().axis, dtype=float)
        else:
            axis[kind] = 1.0
        placement = model.jointPlacements[j]
        plan.R[j - 1][:] = placement.rotation.reshape(9).tolist()
        plan.p[j - 1][:] = placement.translation.tolist()
        plan.axis[j - 1][:] = axis.tolist()
        plan.kind[j - 1] = kind
    plan.flange[:] = frame.placement.act(np.asarray(reflector, dtype=float)).tolist()
    return plan

TRACKER_VARIABLES: tuple[str, ...] = ("tracker.x", "tracker.y", "tracker.z")

DEFAULT_PERIOD_S = 1e-3
"""Sampling period of the tracker, s (paper section 2.3.3: LTD600 at 1 ms)."""

DEFAULT_POSITION_SIGMA_M = 2e-6
"""Laser-tracker position noise, standard deviation per base-frame axis: 2 µm. Source:
the sample-to-sample noise of a Leica LTD600-class tracker at 1 kHz comes from its
resolutions - interferometer 1.26 µm along the beam, angle encoders 0.14 arc s
(0.68 µrad, 1.4 µm at the 2 m of a robot cell) across it - so a couple of µm. Its
+-10 ppm coordinate accuracy (2 sigma, 15-25 µm at 1.5-2.5 m) is a slowly varying
systematic error (angle-encoder and registration errors) that does not change within a
path run; it is not modelled. Scenario key ``[tracker] noise_sigma``; the maximum TCP
error over ~12 000 samples contains about 4.5 sigma of noise (see docs/explanation/main_job.md)."""


class TrackerConfigError(ValueError):
    """A tracker setting is out of range."""


@dataclass(frozen=True)
class TrackerConfig:
    """Laser-tracker settings: period (s), position noise sigma per axis (m), noise seed, and
    where the reflector sits on the tool (m in ``tool0``; default the flange centre)."""

    period_s: float = DEFAULT_PERIOD_S
    noise_sigma_m: float = DEFAULT_POSITION_SIGMA_M
    seed: int = 0
    reflector: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        if not (isinstance(self.period_s, (int, float)) and math.isfinite(self.period_s) and self.period_s > 0):
            raise TrackerConfigError(f"tracker period_s = {self.period_s!r}: expected a number of seconds > 0")
        if not (isinstance(self.noise_sigma_m, (int, float)) and math.isfinite(self.noise_sigma_m)
                and 0.0 <= self.noise_sigma_m <= 1e-3):
            raise TrackerConfigError(f"tracker noise_sigma_m = {self.noise_sigma_m!r}: expected metres in [0, 1e-3]")
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or self.seed < 0:
            raise TrackerConfigError(f"tracker seed = {self.seed!r}: expected an integer >= 0")
        r = np.asarray(self.reflector, dtype=float) if np.ndim(self.reflector) == 1 else None
        if r is None or r.shape != (3,) or not np.all(np.isfinite(r)) or np.linalg.norm(r) > 1.0:
            raise TrackerConfigError(f"tracker reflector = {self.reflector!r}: expected 3 numbers in m (tool0 frame), "
                                     "at most 1 m from the flange centre")


class LaserTracker:
    """Periodic task measuring the true flange position (see module docstring).

    Args:
        true_model: pinocchio model of the TRUE arm kinematics (geometric errors folded in).
        config: :class:`TrackerConfig`.
        joint_signals: the six plant outputs holding the joint angles (rad).
    """

    NOISE_BLOCK = 4096

    def __init__(self, true_model: pin.Model, config: TrackerConfig | None = None,
                 joint_signals: tuple[str, ...] = tuple(f"plant.q[{i}]" for i in range(1, 7))) -> None:
        self.config = config or TrackerConfig()
        self.model = true_model
        self.data = true_model.createData()
        self.frame_id = true_model.getFrameId(FLANGE_FRAME)
        self.joint_signals = joint_signals
        self._rng = np.random.default_rng([self.config.seed, 0x7472])
        self._noise = np.zeros((self.NOISE_BLOCK, 3))
        self._next = self.NOISE_BLOCK
        self._q = None
        self._out = None
        self.samples = 0
        self._sample = None  # the compiled sample (tracker_kernel.c), bound in setup
        self.compiled = False

    def setup(self, master) -> None:
        """Bind to the master (called at the end of its initialize)."""
        self._q = master.reader(list(self.joint_signals))
        self._out = master.view(list(TRACKER_VARIABLES), writable=True)
        library = load_library(KERNEL_SOURCE, what="laser tracker kernel")
        plan = compiled_chain(self.model, self.frame_id, self.config.reflector)
        try:
            q_view = master.view(list(self.joint_signals))
        except ValueError:  # the joint signals are not contiguous on the bus
            q_view = None
        if library is not None and plan is not None and q_view is not None:
            plan.q = q_view.ctypes.data
            plan.out = self._out.ctypes.data
            fn = library.tracker_sample
            fn.argtypes = [ctypes.c_void_p, ctypes.c_void_p]
            fn.restype = None
            self._plan, self._plan_ref, self._q_view = plan, ctypes.byref(plan), q_view
            self._sample = fn
            self.compiled = True

    def _draw(self) -> np.ndarray:
        if self._next == self.NOISE_BLOCK:
            self._refill()
        row = self._noise[self._next]
        self._next += 1
        return row

    def _refill(self) -> None:
        self._noise = self._rng.normal(0.0, self.config.noise_sigma_m, size=(self.NOISE_BLOCK, 3))
        self._noise_address = self._noise.ctypes.data
        self._next = 0

    def flange_position(self, q: np.ndarray) -> np.ndarray:
        """True position (3,) m of the reflector (default: the flange centre) for joint angles
        q (6,) rad (no noise)."""
        pin.forwardKinematics(self.model, self.data, q)
        return pin.updateFramePlacement(self.model, self.data, self.frame_id).act(
            np.asarray(self.config.reflector, dtype=float))

    def __call__(self, t: float) -> None:
        if self._sample is not None:
            if self._next == self.NOISE_BLOCK:
                self._refill()
            self._sample(self._plan_ref, self._noise_address + 24 * self._next)
            self._next += 1
        else:
            position = self.flange_position(self._q.read())
            np.add(position, self._draw(), out=self._out)
        self.samples += 1
