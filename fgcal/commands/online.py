"""``fgcal online``: online recalibration from an inbox of measurement files."""

from __future__ import annotations

import argparse
import signal

from ..core.console import say
from .options import real


def cmd_online(args: argparse.Namespace) -> int:
    from ..online.service import OnlineService

    # SIGTERM (systemd, docker stop) and SIGINT (Ctrl-C) alike: the current measurement is
    # finished, the report written, and the command exits 0.
    stop: list[str] = []

    def request_stop(signum, _frame) -> None:
        if not stop:
            say(f"{signal.Signals(signum).name}: finishing the current measurement, then writing the report")
        stop.append(signal.Signals(signum).name)

    previous = {s: signal.signal(s, request_stop) for s in (signal.SIGTERM, signal.SIGINT)}
    try:
        service = OnlineService(args.state, args.inbox, args.setup, say=say, stop=lambda: bool(stop))
        try:
            service.run(once=args.once, poll_s=args.poll)
        finally:
            service.close()
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
    report = service.report()
    if not report["n_images"]:
        say(f"no measurement folded in yet ({report['n_logged']} logged); nothing written to {args.state}")
        return 0
    accuracy = report["predicted_accuracy"]
    say(
        f"{report['n_images']} measurements; predicted RMS flange sigma {accuracy['rms_m'] * 1e3:#.4g} mm; "
        f"{len(report['alarms'])} drift alarms; wrote {args.state}/report.json, report.md, calibrated_robot.yaml"
        + (f" (stopped by {stop[0]})" if stop else "")
    )
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("online", help="online recalibration: fold measurement files from an inbox into the estimate")
    p.add_argument("--state", required=True, help="state directory (log, checkpoints, outputs)")
    p.add_argument("--inbox", required=True, help="directory where measurement files appear (docs/online.md)")
    p.add_argument("--setup", help="setup YAML for a new state directory (dataset with robot, camera, points)")
    p.add_argument("--once", action="store_true", help="process what is in the inbox, then exit")
    p.add_argument(
        "--poll", type=real(0.0, 3600.0, "s"), default=1.0, help="seconds between looks at the inbox (default 1)"
    )
    p.set_defaults(func=cmd_online)
