"""Assemble a running daemon from its configuration: plan, links, state, socket."""

from __future__ import annotations

import contextlib
import dataclasses
import logging
from dataclasses import dataclass
from typing import Any

from feeder.contact.breakaway import contact
from feeder.contact.tau_pair import tau_pair
from feeder.daemon.camera_moves import PlateMoves
from feeder.daemon.config import DaemonConfig, uses_camera
from feeder.daemon.launcher import Simulator
from feeder.daemon.links import DriverLinks, open_links
from feeder.daemon.service import Daemon, DaemonSetup
from feeder.daemon.step_modes import calibration_key, plan_step_modes
from feeder.daemon.store import Store
from feeder.errors import InputError
from feeder.surface.parameters import DEFAULT_SURFACE, load_surface

log = logging.getLogger(__name__)


@dataclass
class RunningDaemon:
    """A started :class:`Daemon` and the links (and simulator) it owns."""

    daemon: Daemon
    links: DriverLinks

    def stop(self) -> None:
        """Shut the daemon down (output grounded), then stop firmware_sim if we started it."""
        self.daemon.shutdown()
        self.links.close()


def start_daemon(config: DaemonConfig, simulator: Simulator | None = None) -> RunningDaemon:
    """Plan the waveforms, open the links (starting firmware_sim if needed, or taking the one
    :func:`~feeder.daemon.links.spawn_simulator` started), start serving.

    Raises :class:`~feeder.errors.InputError` for an unplannable part or a bad
    socket path, :class:`~feeder.daemon.store.StoreError` for a bad database; whatever
    was started (``simulator`` too) is stopped first.
    """
    with contextlib.ExitStack() as undo:  # on any failure: stop what was started, newest first
        if simulator is not None:
            undo.callback(simulator.stop)
        if config.database_path.exists():  # a bad state file is refused before the simulator is awaited
            Store(config.database_path).close()
        surface = DEFAULT_SURFACE if config.surface_path is None else load_surface(config.surface_path)
        try:  # τ comes with the w it was fitted with: a given τ counts as fitted at w = 0
            pair = tau_pair(surface, config.tau_pa)
        except InputError as err:
            raise InputError("part.tau_pa", err.message) from None
        modes = plan_step_modes(config, surface)
        plane: dict[str, Any] = {}
        key = calibration_key(config.part, config.support, modes)
        if config.plate.planar:
            from feeder.daemon.plane import axis_modes, plan_theta_modes, pose_navigator_factory, theta_key

            static = contact(config.part, config.support, surface, config.tau_pa).breakaway_accel_m_s2
            size = [config.part.length_m, config.part.width_m]
            theta_modes = plan_theta_modes(config, surface, static)
            every_axis = axis_modes(modes, theta_modes, config.plate.axes)
            key = f"{key}/{theta_key(theta_modes)}"
            plane = {
                "axis_modes": every_axis,
                "pose_navigator": pose_navigator_factory(config, every_axis, static),
                "parts": tuple({"shape": "rectangle", "size_m": size} for _ in config.plate.parts),
            }
            if uses_camera(config):
                limits = config.amplifier.limits
                plane["plate_moves"] = PlateMoves(
                    v_min_v=limits.v_min_v,
                    v_max_v=limits.v_max_v,
                    lever_arm_m=config.plate.lever_arm_m,
                    image_px=(config.camera.width_px, config.camera.height_px),
                    stack_gain_m_per_v=config.stack_gain_m_per_v,
                    travel_outside=lambda c: config.camera.travel_outside(c, config.part, config.loop),
                )
        links = open_links(config, simulator)
        undo.callback(links.close)
        setup = DaemonSetup(
            modes=modes,
            loop=config.loop,
            database_path=config.database_path,
            socket_path=config.socket_path,
            calibration_key=key,
            info={
                "part": config.part.label,
                "support": config.support.kind,
                "tau_nominal_pa": pair.tau_pa,
                "tau_source": pair.source,
                "adhesion_work_j_m2": pair.adhesion_work_j_m2,
                "stack": dataclasses.asdict(config.planning_stack),
                "stack_warning": config.stack_warning,
                **links.describe(),
            },
            sensor_timeout_s=config.camera.timeout_s if uses_camera(config) else config.sensor_timeout_s,
            uncalibrated_camera=config.camera.uncalibrated() if uses_camera(config) else None,
            **plane,
        )
        daemon = Daemon(links, setup)
        undo.callback(daemon.shutdown)
        daemon.start()
        undo.pop_all()
    if config.stack_warning is not None:  # once started: a start that fails says only why
        log.warning("%s", config.stack_warning)
    return RunningDaemon(daemon, links)
