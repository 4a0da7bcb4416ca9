"""The devices a session drives, opened from a launch file and always closed again.

A calibration needs an arm, a Muca recorder and, on a simulated rig, the simulated UR
controller and board that stand in for the hardware. ``open_rig`` starts them in the right
order (a simulated board follows the simulated controller's probe through shared memory)
and tears them down in reverse in ``finally``, whatever happened in between. The session
code sees the same ``Rig`` either way: a real rig differs only in where the arm and the
serial port are.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from robot.arm import Arm
from robot.launch import LaunchConfig
from varskin.board.cellmap import CellMap
from varskin.board.recorder import Recorder
from varskin.errors import InputError

# The Muca's ASCII frames run to ~1.35 kB: at 115200 baud a line completes ~0.12 s after
# the board sampled it. The simulated board writes each line at once (no line pacing).
FRAME_BYTES = 1350
SIM_FRAME_RATE_HZ = 8.0  # frames per simulated second, as the real board manages


@dataclass
class Rig:
    launch: LaunchConfig
    arm: Arm
    recorder: Recorder
    cellmap: CellMap
    time_scale: float  # simulated seconds per host second (1 on a real rig)
    frame_latency_s: float  # host seconds from sampling to the line's completion
    truth_xy: np.ndarray | None = None  # a simulated rig's hidden sensor layout (mm)
    board: object | None = None  # the SimBoard, for fault injection in tests
    controller: object | None = None  # the SimulatedController, likewise

    def to_base(self, xy_mm) -> np.ndarray:
        """Patch-frame mm to base-frame m through the registration: the one conversion."""
        return self.launch.frame.to_base(xy_mm)


@contextlib.contextmanager
def open_rig(launch: LaunchConfig, allow_real: bool = False) -> Iterator[Rig]:
    """Start (simulated) or connect (real) everything; ``allow_real`` must be given to drive
    a real robot."""
    if not launch.simulated and not allow_real:
        raise InputError(
            f"{launch.source}: drives a REAL robot; pass --real to confirm the workspace is clear"
        )
    with contextlib.ExitStack() as stack:
        controller = board = None
        truth = None
        scale = launch.sim.time_scale if launch.simulated else 1.0
        if launch.simulated:
            from varskin.board.simboard import SimBoard
            from varskin.cli.robot import start_simulated_controller
            from varskin.scene import Scene, SceneParams

            controller = start_simulated_controller(launch)
            stack.callback(controller.stop)
            scene = Scene.create(
                launch.patch,
                launch.sim.seed,
                SceneParams(inverted=launch.patch.wiring.inverted),
            )
            truth = scene.true_xy.copy()
            board = SimBoard(
                launch.patch,
                scene=scene,
                probe_state=controller.probe_state,
                rate_hz=SIM_FRAME_RATE_HZ,
                baud=None,
                seed=launch.sim.seed,
                time_scale=scale,
            ).start()
            stack.callback(board.stop)
            url, baud, latency = board.path, 115200, 0.0
            host = controller.host
        else:
            url, baud = launch.board.port, launch.board.baud
            latency = FRAME_BYTES * 10 / baud
            host = launch.robot.host
        recorder = Recorder(url, baudrate=baud).start()
        stack.callback(recorder.stop)
        recorder.wait_for_frame(10.0)

        from robot.ur import URArm  # lazily: ur-rtde is needed only to drive an arm

        arm = URArm(host, launch.envelope, **launch.robot.arm_options())
        stack.callback(arm.close)
        arm.connect()
        yield Rig(
            launch=launch,
            arm=arm,
            recorder=recorder,
            cellmap=CellMap.from_patch(launch.patch),
            time_scale=scale,
            frame_latency_s=latency,
            truth_xy=truth,
            board=board,
            controller=controller,
        )
