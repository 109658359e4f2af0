"""``cellcal`` subcommands of the real cell's processes: mocap-bridge, router, register and the fake peers.

Long-running processes (``mocap-bridge``, ``router``, ``fake-controller``, ``fake-motive``) run until SIGINT or
SIGTERM and then exit 0 after closing their sockets and sessions.
"""

from __future__ import annotations

import argparse
import logging
import math
import signal
import threading
from collections.abc import Callable
from typing import Any

import numpy as np

from app.cli.common import cell_spec, non_negative_float, non_negative_int, positive_float, show_progress, write_json
from calibration.errors import CellCalError

log = logging.getLogger("cellcal.app")


def stop_on_signals() -> threading.Event:
    """An event set by SIGINT or SIGTERM (the handlers are installed now, in the main thread)."""
    stop = threading.Event()

    def handler(signum: int, frame: Any) -> None:  # noqa: ARG001 - signal handler signature
        log.warning("%s received: stopping", signal.Signals(signum).name)
        stop.set()

    signal.signal(signal.SIGINT, handler)
    signal.signal(signal.SIGTERM, handler)
    return stop


def _ready(message: str) -> None:
    """One line on stdout when a process serves (scripts and tests wait for it)."""
    print(message, flush=True)


def cmd_mocap_bridge(args: argparse.Namespace) -> int:
    from app.collection.mocap_bridge import BridgeService

    cell = cell_spec(args)
    stop = stop_on_signals()
    service = BridgeService(cell, stop, frame_timeout_s=args.frame_timeout)
    _ready(f"mocap-bridge: NatNet {cell.mocap.server_address} -> zenoh {list(cell.zenoh_for('bridge').listen)} "
           f"(cellcal/{cell.name}/mocap/*); stop with Ctrl-C")
    service.run()
    h = service.health()
    print(f"mocap-bridge stopped: {h.frames_published} frames published, {h.connections} connection(s) and "
          f"{h.handshakes} handshake(s) with Motive")
    write_json(args.json, {"frames_published": h.frames_published, "connections": h.connections,
                           "handshakes": h.handshakes})
    return 0


def cmd_router(args: argparse.Namespace) -> int:
    from drivers.bus import open_session

    cell = cell_spec(args)
    config = cell.zenoh_for("router")
    if config.mode != "router":
        raise CellCalError(f"{cell.path}: zenoh.roles.router.mode must be 'router', got {config.mode!r}")
    stop = stop_on_signals()
    session = open_session(config)
    try:
        zid = str(session.info.zid())
        _ready(f"router: zenoh router {zid} listening on {list(config.listen)}; stop with Ctrl-C")
        stop.wait()
    finally:
        session.close()  # type: ignore[no-untyped-call]  # zenoh's stub leaves close() unannotated
    write_json(args.json, {"zid": zid, "listen": list(config.listen)})
    return 0


def cmd_fake_controller(args: argparse.Namespace) -> int:
    from app.collection.runtime.sim import park_q
    from drivers.motoros.fake_cell import run_fake_controller

    cell = cell_spec(args)
    if cell.controller is None:
        raise CellCalError(f"{cell.path}: no controller block to serve")
    stop = stop_on_signals()
    served: list[Any] = []

    def ready(fake: Any) -> None:
        served.append(fake)
        _ready(f"fake-controller: MotoROS on {fake.host}:{fake.motion_port} (motion) / {fake.state_port} (state), "
               f"groups {dict(cell.controller.groups)}; SIGUSR1 = alarm, SIGUSR2 = non-finite feedback")

    run_fake_controller(cell, stop, initial_q={name: park_q(name) for name in cell.controller.groups},
                        servo_on_delay_s=args.servo_on_delay, on_ready=ready)
    points = 0
    if served:
        points = served[0].points_received
        print(f"fake-controller stopped: trajectory points received: {points}", flush=True)
    write_json(args.json, {"served": bool(served), "trajectory_points_received": points})
    return 0


def cmd_fake_motive(args: argparse.Namespace) -> int:
    from calibration.physics import PlantedErrors
    from drivers.natnet.fake_motive import FakeMotive
    from drivers.sim.rehearsal import RehearsalMocap, StateReader, rehearsal_truths

    cell = cell_spec(args)
    if cell.controller is None or cell.mocap is None:
        raise CellCalError(f"{cell.path}: the fake Motive needs the controller block (to watch the arms) and the "
                           "mocap block (where to serve)")
    stop = stop_on_signals()
    truths = rehearsal_truths(cell, args.seed, PlantedErrors(args.origin_std_mm, math.radians(args.tilt_std_deg),
                                                             args.compliance_mm))
    m = cell.mocap
    if not m.server_address.startswith("127."):
        raise CellCalError(f"{cell.path}: mocap.server_address {m.server_address}: the fake Motive serves on "
                           "loopback only (127.0.0.1)")
    reader = StateReader(cell.controller.host, cell.controller.state_port).start()
    try:
        world = RehearsalMocap(cell, reader, args.seed, truths)
        bodies = {name: 11 + k for k, name in enumerate(m.rigid_bodies.values())}  # Motive's own ids, not ours
        with FakeMotive(bodies, world.poses, rate_hz=args.rate, noise_pos_mm=args.noise_pos_mm,
                        noise_rot_deg=args.noise_rot_deg, seed=args.seed, command_port=m.command_port,
                        data_port=m.data_port, multicast_group=m.multicast_group if m.multicast else None) as motive:
            _ready(f"fake-motive: NatNet 4.1 on {m.server_address}:{m.command_port}, {args.rate:g} Hz, bodies "
                   f"{bodies}, in a hidden world frame (seed {args.seed})")
            stop.wait()
        print(f"fake-motive stopped: {motive.frames_sent} frames sent", flush=True)
    finally:
        reader.close()
    write_json(args.json, {"frames_sent": motive.frames_sent, "bodies": bodies, "seed": args.seed})
    return 0


def cmd_register(args: argparse.Namespace) -> int:
    from app.cli.cell_options import confirm_motion, motion_config, open_runtime, safety_for
    from app.collection.register import base_update_hint, measure_registration, plan_registration, relative_bases
    from cell_config.registration import load_registration, save_registration

    cell = cell_spec(args)
    cell.robot(args.robot)
    if not args.sim and cell.registration_path is None:
        raise CellCalError(f"{cell.path}: no `registration:` file named; add e.g. "
                           f"`registration: {cell.path.stem}.registration.yaml`")
    safety = safety_for(cell, args)
    config = motion_config(cell, args)
    with open_runtime(cell, args, robots=(args.robot,), registered=False) as rt:
        q_now = rt.drivers[args.robot].read_joints().q
        center = np.radians(_floats(args.center, 6, "--center")) if args.center else q_now
        others = {n: d.read_joints().q for n, d in rt.others(args.robot).items()}
        q_plan = plan_registration(cell, args.robot, center, safety, others, q_now, sweep_deg=args.sweep)
        if args.dry_run:
            print(f"{args.robot}: dry run: {len(q_plan)} registration poses around "
                  f"{np.round(np.degrees(center), 1).tolist()} deg, all checked safe; no motion")
            write_json(args.json, {"robot": args.robot, "dry_run": True, "poses": len(q_plan)})
            return 0
        confirm_motion(args, f"{args.robot} will visit {len(q_plan)} registration poses (±{args.sweep:g} deg) at "
                             f"{config.speed_fraction:g} of full speed")
        run = measure_registration(rt, safety, args.robot, q_plan, config, progress=show_progress(args))
    reg = run.registration()
    r = run.result
    out: dict[str, Any] = {"robot": args.robot, "poses": len(run.q), "skipped": [list(s) for s in run.skipped],
                           "rms_mm": r.rms_mm, "rms_deg": r.rms_deg, "max_mm": r.max_mm, "max_deg": r.max_deg,
                           "sigma_world_base": np.asarray(r.sigma_world_base).tolist(),
                           "sigma_flange_marker": np.asarray(r.sigma_flange_marker).tolist(),
                           "T_world_base": np.asarray(r.T_world_base).tolist(),
                           "T_flange_marker": np.asarray(r.T_flange_marker).tolist()}
    print(f"{args.robot}: registered on {len(run.q)} poses: residual rms {r.rms_mm:.4f} mm / {r.rms_deg:.4f} deg, "
          f"max {r.max_mm:.4f} mm; sigma base {np.round(r.sigma_world_base, 4).tolist()} (mm, deg)")
    if args.sim:
        print("simulated cell: the registration is printed, not written")
    else:
        save_registration(cell.registration_path, args.robot, reg)
        print(f"registration written to {cell.registration_path}")
        rel = relative_bases(cell, load_registration(cell.registration_path))
        for name, d in rel.items():
            print(f"{name} base in R1's frame from the registrations differs from cell.yaml by "
                  f"{d['cell_yaml_diff_mm']:.3f} mm / {d['cell_yaml_diff_deg']:.4f} deg")
            hint = base_update_hint(cell, name, d)
            if hint is not None:
                print(hint)
                d["hint"] = hint
        out["relative_bases"] = rel
    write_json(args.json, out)
    return 0


def _floats(text: str, n: int, option: str) -> np.ndarray:
    try:
        values = np.array([float(v) for v in text.split(",")])
    except ValueError:
        raise CellCalError(f"{option}: expected {n} comma-separated numbers, got {text!r}") from None
    if values.shape != (n,) or not np.all(np.isfinite(values)):
        raise CellCalError(f"{option}: expected {n} finite comma-separated numbers, got {text!r}")
    return values


def add_real_parsers(add: Callable[..., argparse.ArgumentParser]) -> None:
    """Register the real-cell process subcommands."""
    from app.cli.cell_options import add_motion_options

    p = add("mocap-bridge", cmd_mocap_bridge, "on the mocap PC: Motive (NatNet) -> Zenoh until stopped")
    p.add_argument("--frame-timeout", type=positive_float, default=2.0,
                   help="seconds without a frame after which Motive counts as gone and is reconnected")
    p.add_argument("--json", help="write the counters at stop (frames published, connections) as JSON")
    p = add("router", cmd_router, "a Zenoh router (eclipse-zenoh's router mode) for cells with more than two machines")
    p.add_argument("--json", help="write the router's id and endpoints at stop as JSON")
    p = add("fake-controller", cmd_fake_controller,
            "rehearsal: a fake MotoROS controller serving every motion group of the cell with simulated arms")
    p.add_argument("--servo-on-delay", type=non_negative_float, default=1.0,
                   help="seconds START_TRAJ_MODE takes to turn the servos on (a real controller: up to ~10)")
    p.add_argument("--json", help="write the trajectory points received, at stop, as JSON")
    p = add("fake-motive", cmd_fake_motive,
            "rehearsal: a fake Motive streaming the fake controller's arms at 240 Hz in a hidden world frame")
    p.add_argument("--seed", type=non_negative_int, default=0, help="seed of the hidden world frame, markers and twins")
    p.add_argument("--rate", type=positive_float, default=240.0, help="frame rate [Hz]")
    p.add_argument("--noise-pos-mm", type=non_negative_float, default=0.02, help="per-frame position noise per axis [mm]")
    p.add_argument("--noise-rot-deg", type=non_negative_float, default=0.005, help="per-frame orientation noise per axis [deg]")
    p.add_argument("--origin-std-mm", type=non_negative_float, default=0.5, help="twins' planted joint-origin errors [mm]")
    p.add_argument("--tilt-std-deg", type=non_negative_float, default=0.05, help="twins' planted joint-axis tilts [deg]")
    p.add_argument("--compliance-mm", type=non_negative_float, default=1.0, help="twins' gravity compliance, RMS [mm]")
    p.add_argument("--json", help="write the frames sent and the body ids, at stop, as JSON")
    p = add("register", cmd_register, "register the mocap world to an arm's base and its marker to the flange")
    p.add_argument("--robot", required=True, help="robot name in the cell (R1, R2)")
    p.add_argument("--center", help="centre pose of the registration plan, 6 comma-separated angles [deg] "
                                    "(default: where the arm stands)")
    p.add_argument("--sweep", type=positive_float, default=20.0, help="rotation of each joint about the centre [deg]")
    p.add_argument("--json", help="write the registration and its residuals as JSON")
    add_motion_options(p)

