"""Built-in motions: procedural, natural-looking pose sequences, so the pipeline needs no motion data.

Each motion is a few seconds of smooth joint-angle curves (sinusoids, raised-cosine bumps, smootherstep
envelopes and, for gaits, curvature-penalised Fourier series through textbook keyframes, so angular
accelerations stay bounded) in SMPL's 24-joint layout and the project's frame (Z up,
metres, the body facing -Y, its left along +X; see `assets.body.model`).  Every motion starts and ends at
rest: the motions in place in their neutral pose (standing, arms hanging; the T-pose for 'tpose'), eased
in and out; walk and run in a stride's double-support stance, their stride clock speeding up from and
slowing down to a standstill.

The root path comes from the body (`grounded_trans`): the pelvis height keeps the lowest point of the
soles on the ground (z = 0) and, for motions with planted feet, the pelvis moves so that the feet on the
ground do not slide.  So a walk advances by its own strides, and a squat sits back over the heels.

``speed`` multiplies every cycle frequency (strides, squats, turns per motion); ``amplitude`` scales every
excursion from the neutral pose (joint angles, the jump's flight, the spin's turn): 0 holds the neutral
pose, 1 is natural; above about 1.2 the forearms of 'run' and 'arm_swing' reach the torso, and joint
accelerations grow with amplitude and with the square of speed (bounded for amplitude and speed 1).

Signs, checked against the default body (rotation vectors are in the parent's rest-aligned frame, for
the left side; the right side mirrors them through the body's sagittal plane, x -> -x):
hip flexion (leg forward) -X, knee flexion +X, ankle dorsiflexion (toes up) -X, spine flexion (bending
forward) +X, lateral bend to the left +Y, turning to the left +Z; the arm lowers from the T-pose about +Y,
then flexes (forward) about -X; the elbow flexes about -Z.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from assets.body.default import default_body
from assets.body.model import NUM_SMPL_JOINTS, SMPL_JOINT_NAMES, BodyModel
from assets.motion.ground import grounded_trans
from assets.motion.motion import MAX_FRAMES, SIMULATION_FPS, Motion, check_fps, check_frames
from assets.rotations import matrix_to_rotvec, rotvec_to_matrix

X, Y, Z = 0, 1, 2
#: Neutral standing: each arm lowered this far below horizontal (15 degrees abducted, hands clear the
#: hips) with the elbows slightly bent.
ARM_HANG_DEG = 75.0
ELBOW_REST_DEG = 10.0
_J = {name: j for j, name in enumerate(SMPL_JOINT_NAMES)}
_SPINE_SHARE = {"spine1": 0.3, "spine2": 0.3, "spine3": 0.4}


# -- curves ------------------------------------------------------------------------------------------


def smootherstep(x: np.ndarray) -> np.ndarray:
    """0 -> 1 on [0, 1] with zero first and second derivatives at both ends; clamped outside."""
    x = np.clip(x, 0.0, 1.0)
    return x * x * x * (x * (6.0 * x - 15.0) + 10.0)


def _bump(x: np.ndarray, centre: float, half_width: float) -> np.ndarray:
    """Raised-cosine bump: 1 at `centre`, falling to 0 (zero slope) at centre +- half_width, 0 beyond."""
    u = np.clip((x - centre) / half_width, -1.0, 1.0)
    return 0.5 * (1.0 + np.cos(np.pi * u))


@dataclass(frozen=True)
class Clock:
    """The time base a generator draws on: frame times ``t`` (T,) seconds from 0 to ``seconds``, the
    cycle-rate multiplier ``speed`` and the excursion scale ``amplitude``."""

    t: np.ndarray
    seconds: float
    speed: float
    amplitude: float

    def phase(self, hz: float) -> np.ndarray:
        """(T,) radians of a cycle that runs at `hz` at speed 1."""
        return 2.0 * np.pi * hz * self.speed * self.t

    def cycle_time(self, period: float) -> np.ndarray:
        """(T,) seconds into the current cycle of `period` seconds at speed 1."""
        return np.mod(self.speed * self.t, period)

    def envelope(self, ramp: float) -> np.ndarray:
        """(T,) the amplitude, eased in over the first `ramp` seconds and out over the last."""
        return self.amplitude * smootherstep(self.t / ramp) * smootherstep((self.seconds - self.t) / ramp)

    def eased_time(self, ramp: float) -> np.ndarray:
        """(T,) seconds of a clock that starts from a standstill, runs at full rate after `ramp` seconds
        and stops again at the end: the integral of the smootherstep ease in and out (ramps shortened
        to half the length when they would overlap)."""
        ramp = min(ramp, self.seconds / 2.0)

        def eased(x):  # integral of smootherstep from 0 to x
            u = np.clip(x, 0.0, 1.0)
            return u**4 * (u * (u - 3.0) + 2.5) + np.maximum(x - 1.0, 0.0)

        return ramp * (eased(self.t / ramp) - eased((self.t - self.seconds + ramp) / ramp))


# -- poses from anatomical angles ----------------------------------------------------------------------


class _Pose:
    """Local joint rotations (T, 24, 3, 3) set from anatomical angles in degrees (scalars or (T,))."""

    def __init__(self, frames: int):
        self.frames = frames
        self.rotations = np.broadcast_to(np.eye(3), (frames, NUM_SMPL_JOINTS, 3, 3)).copy()

    def turn(self, axis: int, degrees) -> np.ndarray:
        """(T, 3, 3) rotations by `degrees` about a rest-frame axis."""
        angle = np.broadcast_to(np.deg2rad(np.asarray(degrees, dtype=np.float64)), (self.frames,))
        return rotvec_to_matrix(angle[:, None] * np.eye(3)[axis])

    def set(self, joint: str, *turns: tuple[int, object], side: int = 0) -> None:
        """Joint rotation = the `turns` (axis, degrees) applied in order (the first innermost).  Named
        without its side, a limb joint takes `side` +1 (left, angles as given) or -1 (right, mirrored)."""
        name = joint if side == 0 else ("left_" if side > 0 else "right_") + joint
        rotation = np.broadcast_to(np.eye(3), (self.frames, 3, 3))
        for axis, degrees in turns:
            mirror = -1.0 if side < 0 and axis != X else 1.0
            rotation = self.turn(axis, mirror * degrees) @ rotation
        self.rotations[:, _J[name]] = rotation

    def root(self, tilt=0.0, hike=0.0, yaw=0.0) -> None:
        """Pelvis in the world: forward `tilt`, left side raised by `hike`, turned to the left by `yaw`."""
        self.set("pelvis", (Y, -hike), (X, tilt), (Z, yaw))

    def leg(self, side: int, hip, knee, dorsi=0.0, toes=0.0, adduct=0.0, outward=0.0) -> None:
        """Hip flexion, knee flexion, ankle dorsiflexion, toe extension, hip adduction and outward turn."""
        self.set("hip", (Z, outward), (Y, adduct), (X, -hip), side=side)
        self.set("knee", (X, knee), side=side)
        self.set("ankle", (X, -dorsi), side=side)
        self.set("foot", (X, -toes), side=side)

    def arm(self, side: int, lower=ARM_HANG_DEG, flex=0.0, forward=0.0, elbow=ELBOW_REST_DEG, outward=0.0,
            shrug=0.0) -> None:
        """Shoulder: turn `outward` about the arm, `lower` below horizontal, swing `forward` in the
        horizontal plane, `flex` forward in the sagittal plane (in that order); then the elbow's flexion
        and the collar's `shrug` (raising the shoulder)."""
        self.set("collar", (Y, -shrug), side=side)
        self.set("shoulder", (X, -outward), (Y, lower), (Z, -forward), (X, -flex), side=side)
        self.set("elbow", (Z, -elbow), side=side)

    def trunk(self, flex=0.0, bend=0.0, twist=0.0, nod=0.0, look=0.0) -> None:
        """Spine flexion, lateral bend to the left, twist to the left (shared over spine1..3); head `nod`
        (flexion) and `look` (turn to the left), shared over neck and head."""
        for joint, share in _SPINE_SHARE.items():
            self.set(joint, (Z, share * twist), (Y, share * bend), (X, share * flex))
        for joint in ("neck", "head"):
            self.set(joint, (Z, 0.5 * look), (X, 0.5 * nod))

    def poses(self) -> np.ndarray:
        """(T, 24, 3) axis-angle radians."""
        return matrix_to_rotvec(self.rotations)


@dataclass(frozen=True)
class Kinematics:
    """What a generator makes: poses (T, 24, 3) radians, extra pelvis ``lift`` (T,) metres above the
    grounded height (a jump's flight), whether feet on the ground stay put (``planted``), and which feet
    may carry the body: ``support`` (T, 2) for the left and right foot, 1 standing, 0 swinging through
    the air (None: both may)."""

    poses: np.ndarray
    lift: np.ndarray | float = 0.0
    planted: bool = True
    support: np.ndarray | None = None


# -- gaits ---------------------------------------------------------------------------------------------


Keyframes = tuple[tuple[float, float], ...]
#: Harmonics and curvature penalty of the smooth periodic curves through gait keyframes.
_HARMONICS = 6
_CURVATURE_PENALTY = 0.01


@dataclass(frozen=True)
class GaitStyle:
    """A walking or running stride.  Sagittal leg angles are keyframes (percent of the stride from this
    leg's heel strike, degrees), the rest amplitudes in degrees; the right leg runs half a stride behind."""

    stride_hz: float
    ramp_seconds: float
    toe_off: float  # percent of the stride: the foot is in the air from here to the heel strike
    hip: Keyframes  # flexion
    knee: Keyframes  # flexion
    ankle: Keyframes  # dorsiflexion (toes up) +, plantarflexion -
    toes: Keyframes  # extension
    hip_adduction: tuple[float, float]  # mean (feet under the body), swing with the pelvis list
    pelvis_list: float  # the swing side drops
    pelvis_yaw: float  # the swing side leads
    pelvis_tilt: float  # forward
    trunk_flex: float
    trunk_counter: float  # thorax twist against the pelvis
    arm_swing: float
    arm_lower: float
    arm_forward: float  # arms swing towards the midline
    elbow: tuple[float, float]  # mean flexion, swing


WALK = GaitStyle(
    stride_hz=0.9, ramp_seconds=1.0, toe_off=62.0,
    hip=((0, 22), (10, 20), (20, 12), (30, 2), (40, -8), (50, -15), (56, -17), (62, -12), (70, 4), (80, 18),
         (88, 24), (100, 22)),
    knee=((0, 4), (6, 10), (15, 17), (25, 12), (35, 6), (42, 5), (50, 10), (60, 36), (67, 55), (73, 60), (80, 50),
          (90, 22), (96, 7), (100, 4)),
    ankle=((0, 0), (7, -6), (15, -1), (30, 6), (45, 10), (52, 6), (57, -3), (62, -16), (70, -8), (80, 1), (90, 2),
           (100, 0)),
    toes=((0, 0), (30, 0), (45, 8), (55, 25), (62, 30), (70, 12), (80, 0), (100, 0)),
    hip_adduction=(5.0, 6.0), pelvis_list=4.0, pelvis_yaw=5.0, pelvis_tilt=2.0, trunk_flex=2.0,
    trunk_counter=8.0, arm_swing=16.0, arm_lower=ARM_HANG_DEG, arm_forward=0.0, elbow=(20.0, 10.0),
)  # fmt: skip
RUN = GaitStyle(
    stride_hz=1.3, ramp_seconds=1.0, toe_off=40.0,
    hip=((0, 28), (10, 22), (20, 10), (30, -2), (40, -10), (50, -2), (60, 14), (70, 28), (80, 37), (86, 39),
         (92, 37), (100, 28)),
    knee=((0, 18), (10, 34), (18, 38), (28, 28), (38, 18), (48, 40), (58, 72), (68, 88), (76, 84), (86, 58),
          (94, 32), (100, 18)),
    ankle=((0, 5), (10, 14), (20, 18), (30, 8), (40, -20), (48, -14), (58, -2), (70, 5), (80, 6), (90, 5),
           (100, 5)),
    toes=((0, 0), (20, 3), (32, 20), (40, 30), (48, 15), (58, 0), (100, 0)),
    hip_adduction=(5.0, 7.0), pelvis_list=5.0, pelvis_yaw=7.0, pelvis_tilt=5.0, trunk_flex=6.0,
    trunk_counter=12.0, arm_swing=28.0, arm_lower=80.0, arm_forward=8.0, elbow=(85.0, 12.0),
)  # fmt: skip


def _fourier_basis(phase: np.ndarray) -> np.ndarray:
    """(N, 2H + 1): 1, cos(k phase), sin(k phase) for k = 1..H at phases (N,) radians."""
    k = np.multiply.outer(phase, np.arange(1, _HARMONICS + 1))
    return np.concatenate([np.ones(np.shape(phase) + (1,)), np.cos(k), np.sin(k)], axis=-1)


def periodic_curve(keys: Keyframes, phase: np.ndarray) -> np.ndarray:
    """(T,) degrees at `phase` (T,) radians of a smooth periodic curve through `keys` (percent, degrees):
    the Fourier series of `_HARMONICS` harmonics that fits them best under a penalty on its curvature,
    so its second derivative (the angular acceleration) stays small."""
    at = np.array([key[0] for key in keys]) * (2.0 * np.pi / 100.0)
    value = np.array([key[1] for key in keys], dtype=np.float64)
    basis = _fourier_basis(at)
    k = np.arange(1, _HARMONICS + 1, dtype=np.float64)
    penalty = np.diag(np.concatenate([[0.0], k**4, k**4]))
    coefficients = np.linalg.solve(basis.T @ basis + _CURVATURE_PENALTY * penalty, basis.T @ value)
    return _fourier_basis(phase) @ coefficients


def gait(clock: Clock, style: GaitStyle) -> Kinematics:
    """A straight walk or run along -Y, starting and stopping with both feet on the ground (one heel
    striking, the other foot about to push off): the stride's clock speeds up from a standstill over
    `style.ramp_seconds` and slows to one at the end (`Clock.eased_time`), so the steps are the natural
    ones throughout and planted feet never drag; the stride rate is rounded down to end on a heel strike.
    The arms swing against the legs; the pelvis turns, drops on the swing side and shifts over the
    stance foot; the thorax twists against it and the head keeps looking ahead."""
    gain = clock.amplitude
    elapsed = clock.eased_time(style.ramp_seconds)
    strides = np.floor(2.0 * style.stride_hz * clock.speed * elapsed[-1]) / 2.0  # end on a heel strike
    phase = 2.0 * np.pi * strides * elapsed / elapsed[-1]
    pose = _Pose(len(clock.t))
    support = []
    for side, offset in ((1, 0.0), (-1, np.pi)):
        p = phase + offset
        pose.leg(side,
                 hip=gain * periodic_curve(style.hip, p),
                 knee=gain * periodic_curve(style.knee, p),
                 dorsi=gain * periodic_curve(style.ankle, p),
                 toes=gain * periodic_curve(style.toes, p),
                 adduct=gain * (style.hip_adduction[0] + style.hip_adduction[1] * np.cos(p - 1.0)))
        counter = -np.cos(p + 0.75)  # forward as this side's hip extends (its flexion peaks at 88 %)
        pose.arm(side,
                 lower=ARM_HANG_DEG + gain * (style.arm_lower - ARM_HANG_DEG),
                 flex=gain * style.arm_swing * counter,
                 forward=gain * style.arm_forward,
                 elbow=ELBOW_REST_DEG + gain * (style.elbow[0] - ELBOW_REST_DEG + style.elbow[1] * counter))
        # On the ground from heel strike to toe-off, with smootherstep edges 2 % of a stride wide.
        stride = np.mod(p / (2.0 * np.pi), 1.0)
        edge, toe_off = 0.02, style.toe_off / 100.0
        support.append(1.0 - smootherstep((stride - toe_off) / edge) * smootherstep((1.0 - stride) / edge))
    pose.root(tilt=gain * (style.pelvis_tilt + 1.5 * np.cos(2.0 * phase)),
              hike=gain * style.pelvis_list * np.cos(phase - 1.0),
              yaw=-gain * style.pelvis_yaw * np.cos(phase))
    pose.trunk(flex=gain * style.trunk_flex, twist=gain * style.trunk_counter * np.cos(phase),
               nod=-gain * (style.pelvis_tilt + style.trunk_flex),
               look=-gain * (style.trunk_counter - style.pelvis_yaw) * np.cos(phase))
    return Kinematics(pose.poses(), support=np.stack(support, axis=1))


def walk(clock: Clock) -> Kinematics:
    return gait(clock, WALK)


def run(clock: Clock) -> Kinematics:
    return gait(clock, RUN)


# -- in place ------------------------------------------------------------------------------------------


def _crouch(pose: _Pose, depth, tilt, hip, knee, plantar=0.0, toes=0.0) -> None:
    """Both legs flexed by `depth` (T,) times `hip` and `knee` degrees, thighs slightly apart, the
    pelvis tilted forward by `depth * tilt`; the ankles dorsiflexed by ``tilt - hip + knee`` (which keeps
    the soles level) less `plantar` degrees, the toes extended by `toes`."""
    for side in (1, -1):
        pose.leg(side, hip=depth * hip, knee=depth * knee, dorsi=depth * (tilt - hip + knee) - plantar, toes=toes,
                 adduct=-depth * 8.0, outward=depth * 10.0)
    pose.root(tilt=depth * tilt)


def squat(clock: Clock) -> Kinematics:
    """Squats to thighs level, heels down, arms reaching forward for balance; one every 2 s."""
    depth = clock.envelope(0.3) * 0.5 * (1.0 - np.cos(clock.phase(0.5)))
    pose = _Pose(len(clock.t))
    _crouch(pose, depth, tilt=25.0, hip=112.0, knee=115.0)
    pose.trunk(flex=-depth * 5.0, nod=-depth * 20.0)
    for side in (1, -1):
        pose.arm(side, flex=depth * 85.0, lower=ARM_HANG_DEG - depth * 5.0)
    return Kinematics(pose.poses())


def jump(clock: Clock) -> Kinematics:
    """Vertical jumps, one every 2 s: crouch with the arms swung back, push off on the toes as the arms
    swing up, about 0.45 s of flight with pointed feet, land into a softer crouch, stand."""
    gain = clock.envelope(0.25)
    s = clock.cycle_time(2.0)
    crouch = gain * (_bump(s, 0.6, 0.4) + 0.6 * _bump(s, 1.55, 0.3))
    point = gain * _bump(s, 1.1, 0.3)  # ankles extended from push-off to landing
    pose = _Pose(len(clock.t))
    _crouch(pose, crouch, tilt=25.0, hip=80.0, knee=85.0, plantar=point * 35.0,
            toes=gain * 25.0 * _bump(s, 0.95, 0.15))
    swing = gain * (-40.0 * _bump(s, 0.6, 0.35) + 150.0 * _bump(s, 1.1, 0.35))
    for side in (1, -1):
        pose.arm(side, flex=swing, elbow=ELBOW_REST_DEG + gain * 15.0 * _bump(s, 0.6, 0.4),
                 shrug=gain * 12.0 * _bump(s, 1.1, 0.3))
    pose.trunk(flex=crouch * 10.0, nod=-crouch * 25.0)
    flight = np.clip((s - 1.15) / 0.25, -1.0, 1.0)
    lift = gain * 0.15 * (1.0 - flight * flight) ** 2  # falls at 4 * 0.15 / 0.25^2 = 9.6 m/s^2 at its top
    return Kinematics(pose.poses(), lift=lift)


def arm_raise(clock: Clock) -> Kinematics:
    """Both arms up overhead and down again every 2 s: first out to the sides, then through the front."""
    gain = clock.envelope(0.3)
    s = clock.cycle_time(4.0)
    side_up = gain * _bump(s, 1.0, 1.0)
    front_up = gain * _bump(s, 3.0, 1.0)
    pose = _Pose(len(clock.t))
    for side in (1, -1):
        pose.arm(side, lower=ARM_HANG_DEG - 155.0 * side_up, flex=165.0 * front_up,
                 elbow=ELBOW_REST_DEG + 10.0 * (side_up + front_up), shrug=15.0 * (side_up + front_up) ** 2)
    pose.trunk(flex=-4.0 * (side_up + front_up), nod=-8.0 * (side_up + front_up))
    return Kinematics(pose.poses())


def arm_swing(clock: Clock) -> Kinematics:
    """Arm swings at 0.8 Hz: first alternating forward and back, then (second half) raised to the front
    and swung open and across, the left arm above the right where they cross."""
    gain = clock.envelope(0.3)
    half = clock.seconds / 2.0
    sagittal = gain * smootherstep((half - clock.t) / 0.5)
    across = gain * smootherstep((clock.t - half) / 0.5)
    phase = clock.phase(0.8)
    pose = _Pose(len(clock.t))
    for side, height in ((1, 65.0), (-1, 45.0)):
        pose.arm(side, flex=sagittal * side * 55.0 * np.sin(phase),
                 lower=ARM_HANG_DEG - across * height,
                 forward=across * (50.0 - 65.0 * np.cos(phase)),
                 elbow=ELBOW_REST_DEG + sagittal * 15.0 * (1.0 + side * np.sin(phase)) + across * 10.0)
    pose.trunk(twist=sagittal * 6.0 * np.sin(phase))
    return Kinematics(pose.poses())


def bend(clock: Clock) -> Kinematics:
    """Every 4 s: a forward bend from the hips with the arms hanging towards the shins, then side bends
    to the left and right with the arms overhead."""
    gain = clock.envelope(0.3)
    s = clock.cycle_time(4.0)
    forward = gain * _bump(s, 1.0, 1.0)
    overhead = gain * _bump(s, 3.0, 1.0)
    lateral = overhead * np.sin(np.pi * (s - 2.0))  # left, then right
    pose = _Pose(len(clock.t))
    for side in (1, -1):
        pose.leg(side, hip=forward * 50.0, knee=forward * 8.0, dorsi=forward * 8.0)
        pose.arm(side, flex=forward * 85.0, lower=ARM_HANG_DEG - overhead * 150.0, elbow=ELBOW_REST_DEG)
    pose.root(tilt=forward * 50.0)
    pose.trunk(flex=forward * 45.0, bend=lateral * 30.0, nod=forward * 10.0 - overhead * 5.0)
    return Kinematics(pose.poses())


def spin(clock: Clock) -> Kinematics:
    """A turn to the left through 360 degrees (times speed) on the spot, with small alternating steps,
    arms a little out, the head and thorax leading the turn."""
    x = clock.t / clock.seconds
    turning = clock.amplitude * 16.0 * x * x * (1.0 - x) * (1.0 - x)  # turn rate, 1 at its peak
    phase = clock.phase(1.25)
    pose = _Pose(len(clock.t))
    for side, offset in ((1, 0.0), (-1, np.pi)):
        step = turning * np.maximum(np.sin(phase + offset), 0.0) ** 2  # each foot lifts in turn
        pose.leg(side, hip=25.0 * step, knee=40.0 * step, dorsi=10.0 * step)
        pose.arm(side, lower=ARM_HANG_DEG - 20.0 * turning, elbow=ELBOW_REST_DEG + 15.0 * turning)
    pose.root(yaw=clock.amplitude * 360.0 * clock.speed * smootherstep(x))
    pose.trunk(twist=15.0 * turning, look=20.0 * turning)
    return Kinematics(pose.poses(), planted=False)


def wave(clock: Clock) -> Kinematics:
    """The right hand raised beside the head, waving (the forearm sweeping side to side at 2 Hz)."""
    raised = clock.envelope(0.6)
    sweep = np.sin(clock.phase(2.0))
    pose = _Pose(len(clock.t))
    pose.arm(-1, lower=ARM_HANG_DEG - raised * 95.0, forward=raised * 15.0, outward=raised * 90.0,
             elbow=ELBOW_REST_DEG + raised * (60.0 + 25.0 * sweep))
    pose.arm(1)
    pose.trunk(bend=raised * 3.0, nod=raised * 3.0 * sweep, look=-raised * 10.0)
    return Kinematics(pose.poses())


def tpose(clock: Clock) -> Kinematics:
    """The T-pose held, breathing: the chest rises and the arms sway a little every 4 s."""
    breath = clock.envelope(0.5) * np.sin(clock.phase(0.25))
    pose = _Pose(len(clock.t))
    for side in (1, -1):
        pose.arm(side, lower=2.0 * breath, elbow=breath, shrug=breath)
    pose.trunk(flex=-1.5 * breath)
    return Kinematics(pose.poses())


# -- registry ------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class BuiltinMotion:
    """A registered motion: its generator and default length in seconds."""

    generate: Callable[[Clock], Kinematics]
    seconds: float


BUILTIN_MOTIONS: dict[str, BuiltinMotion] = {
    "walk": BuiltinMotion(walk, 5.0),
    "run": BuiltinMotion(run, 4.0),
    "arm_raise": BuiltinMotion(arm_raise, 4.0),
    "arm_swing": BuiltinMotion(arm_swing, 5.0),
    "squat": BuiltinMotion(squat, 4.0),
    "jump": BuiltinMotion(jump, 4.0),
    "spin": BuiltinMotion(spin, 4.0),
    "bend": BuiltinMotion(bend, 4.0),
    "wave": BuiltinMotion(wave, 3.0),
    "tpose": BuiltinMotion(tpose, 3.0),
}


def list_builtin_motions() -> list[str]:
    """Names of the built-in motions, sorted."""
    return sorted(BUILTIN_MOTIONS)


def builtin_motion(
    name: str,
    seconds: float | None = None,
    fps: float = SIMULATION_FPS,
    speed: float = 1.0,
    amplitude: float = 1.0,
    body: BodyModel | None = None,
    max_frames: int = MAX_FRAMES,
) -> Motion:
    """The built-in motion `name` (see `BUILTIN_MOTIONS`) over `seconds` (None: its default) at `fps`,
    with cycles `speed` times as fast and excursions scaled by `amplitude` (>= 0).  The root path is
    grounded on `body` (None: the default body); frames ``round(seconds * fps) + 1``, at most
    `max_frames`."""
    if name not in BUILTIN_MOTIONS:
        raise ValueError(f"unknown built-in motion {name!r}; known: {', '.join(list_builtin_motions())}")
    entry = BUILTIN_MOTIONS[name]
    seconds = entry.seconds if seconds is None else float(seconds)
    for label, value in (("seconds", seconds), ("fps", fps), ("speed", speed)):
        if not (np.isfinite(value) and value > 0):
            raise ValueError(f"built-in motion {name!r}: {label} must be positive, got {value}")
    fps = check_fps(fps, f"built-in motion {name!r}")
    check_frames(round(seconds * fps) + 1, f"built-in motion {name!r} over {seconds:g} s at {fps:g} Hz", max_frames)
    frames = int(round(seconds * fps)) + 1
    if frames < 2:
        raise ValueError(f"built-in motion {name!r}: {seconds} s at {fps} Hz is less than one frame interval")
    if not (np.isfinite(amplitude) and amplitude >= 0):
        raise ValueError(f"built-in motion {name!r}: amplitude must be >= 0, got {amplitude}")
    body = default_body() if body is None else body
    t = np.arange(frames) / fps
    made = entry.generate(Clock(t=t, seconds=t[-1], speed=float(speed), amplitude=float(amplitude)))
    trans = grounded_trans(body, made.poses, fps, made.lift, made.planted, made.support)
    return Motion(poses=made.poses, trans=trans, fps=float(fps), name=name, source="builtin")
