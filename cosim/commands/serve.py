"""``python -m cosim serve SCENARIO [--out DIR] [--channel HOST:PORT] [--peer HOST:PORT] ...``:
the cell side of a hardware-in-the-loop run (docs/how-to/served_cell.md)."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

NAME = "serve"
HELP = ("Run the cell side of the scenario's robot-cell runs (plant, drives, controlled nodes, tracker, "
        "recorder) paced at the bus cycle for a controller in another program on the udpcycle bus; "
        "writes hil_endpoint.json first, then the usual results (docs/how-to/served_cell.md).")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from cosim.execution.serve_settings import (DEFAULT_CHANNEL, DEFAULT_SPIN_S, DEFAULT_SYNC_TIMEOUT_S,
                                                DEFAULT_WINDOW_FRACTION, UDPCYCLE)

    parser.add_argument("scenario", type=Path, help="scenario TOML file of a robot-cell job (e.g. scenarios/hil.toml)")
    parser.add_argument("--out", type=Path, default=None, help="results folder (default results/<scenario name>/)")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    parser.add_argument("--interface", default=UDPCYCLE,
                        help=f"the bus: {UDPCYCLE} (default; one datagram per POWERLINK cycle for a controller of "
                             "docs/how-to/served_cell.md) or any python-can interface (udp_multicast, virtual, socketcan, pcan, "
                             "kvaser, ...): then the six drives are CANopen devices and a CANopen master's SYNC "
                             "drives the cell (docs/how-to/can_master.md)")
    parser.add_argument("--channel", default=None,
                        help=f"udpcycle: the cell's address host:port, unicast or a multicast group (default "
                             f"{DEFAULT_CHANNEL}); another interface: its channel (e.g. 239.74.163.2 for "
                             "udp_multicast, can0 for socketcan, PCAN_USBBUS1 for pcan), required")
    parser.add_argument("--bitrate", type=int, default=None,
                        help="python-can interfaces: the bus bit rate, bit/s (e.g. 1000000); passed to can.Bus")
    parser.add_argument("--bus-option", action="append", default=[], metavar="KEY=VALUE",
                        help="python-can interfaces: one more keyword of can.Bus (repeatable), e.g. port=43113, "
                             "fd=true, data_bitrate=5000000; numbers and true/false are converted")
    parser.add_argument("--sync-timeout", type=float, default=DEFAULT_SYNC_TIMEOUT_S, metavar="S",
                        help="python-can interfaces: end the run S seconds after the master's last SYNC (default "
                             f"{DEFAULT_SYNC_TIMEOUT_S:g})")
    parser.add_argument("--peer", default=None,
                        help="the controller's host:port (default: learned from the first valid datagram; from then on "
                             "only that sender is accepted unless --accept-from lists more)")
    parser.add_argument("--accept-from", default=None,
                        help="comma-separated hosts or host:port accepted as the controller (default: any)")
    parser.add_argument("--window", type=float, default=DEFAULT_WINDOW_FRACTION,
                        help="fraction of the cycle the cell waits for the controller's frames (default "
                             f"{DEFAULT_WINDOW_FRACTION})")
    parser.add_argument("--spin-us", type=float, default=DEFAULT_SPIN_S * 1e6,
                        help="busy-wait before each cycle deadline, us")
    parser.add_argument("--busy-poll-us", type=float, default=0.0, help="spin on the socket while waiting, us")
    parser.add_argument("--scheduling", choices=("fifo", "normal"), default="fifo",
                        help="SCHED_FIFO when the OS grants it (default) or normal")
    parser.add_argument("--cpu", default=None, help="pin to this CPU ('auto': the last usable one)")
    parser.add_argument("--wait-for-controller", type=float, default=None, metavar="S",
                        help="wait up to S seconds for the controller's first datagram and start the run "
                             "(cycle 0) then (default: start at once)")


def run(args: argparse.Namespace) -> int:
    from cosim.api import OutputFolderError, RunResult, ScenarioError, execute, load_scenario
    from cosim.results.exits import InvalidInput, signal_name_of
    from cosim.execution.serve_settings import ServeSettings, ServeSettingsError

    from cosim.execution.serve_settings import DEFAULT_CHANNEL, UDPCYCLE

    interface = str(args.interface).strip()
    if interface != UDPCYCLE and args.channel is None:
        raise InvalidInput(f"--interface {interface!r}: expected --channel too (the interface's channel, e.g. "
                           f"239.74.163.2 for udp_multicast, can0 for socketcan)")
    try:
        settings = ServeSettings(channel=args.channel if args.channel is not None else DEFAULT_CHANNEL,
                                 interface=interface, bitrate=args.bitrate, bus_kwargs=_bus_options(args.bus_option),
                                 sync_timeout_s=args.sync_timeout, peer=args.peer,
                                 accept_from=None if args.accept_from is None else
                                 tuple(x.strip() for x in args.accept_from.split(",") if x.strip()),
                                 window_fraction=args.window, spin_s=args.spin_us * 1e-6,
                                 busy_poll_s=args.busy_poll_us * 1e-6, scheduling=args.scheduling, cpu=args.cpu,
                                 wait_for_controller_s=args.wait_for_controller)
    except ServeSettingsError as exc:
        raise InvalidInput(str(exc)) from None
    if settings.canopen:
        _check_can_bus(settings)
    else:
        _check_address_free(settings.channel)
    _check_cpu_and_hosts(args.cpu, settings.accept_from, settings.peer)
    try:
        scenario = load_scenario(args.scenario)
    except ScenarioError as exc:
        raise InvalidInput(str(exc)) from None
    out_dir = args.out if args.out is not None else Path("results") / scenario.name
    origin = "--out" if args.out is not None else "results folder"
    try:
        result = execute(scenario, out_dir, quiet=args.quiet, origin=origin, serve=settings)
    except (ScenarioError, OutputFolderError) as exc:
        raise InvalidInput(str(exc)) from None
    except KeyboardInterrupt as exc:
        summary = RunResult(out_dir).summary
        print(f"{scenario.name}: serve interrupted by {signal_name_of(exc)}"
              f"{'' if summary.stopped_at_s is None else f' at t = {summary.stopped_at_s:.6g} s'}; results in "
              f"{out_dir}/", file=sys.stderr)
        return 130
    _warn_cycle_time_mismatch(result.summary.raw.get("hil") or {})
    _warn_transport_faults(result.summary.raw.get("hil") or {})
    _report_losses(result.summary.raw.get("hil") or {})
    from cosim.cell.verdict import exit_code
    from cosim.commands.run import print_run_lines

    print_run_lines(result.summary.raw, args.quiet)
    if result.ok:
        if not args.quiet:
            print(f"{scenario.name}: served, results in {out_dir}/", file=sys.stderr)
        return 0
    status = result.summary.status
    if status in ("limit", "fault"):  # completed, but the drives reacted (e.g. tripped on lost cycles)
        print(f"{scenario.name}: served, {status}: {(result.summary.reason or '').strip()}; results in {out_dir}/ "
              f"(summary.json: {status}, exit code {exit_code(status)}, docs/reference/verdicts.md)", file=sys.stderr)
        return exit_code(status)
    print(f"error: {scenario.name}: served run failed: {(result.summary.reason or '').strip()}", file=sys.stderr)
    return 3


def _bus_options(items: list[str]) -> dict:
    """``--bus-option KEY=VALUE`` items as can.Bus keywords (int, float, true/false converted)."""
    from cosim.results.exits import InvalidInput

    options: dict = {}
    for item in items:
        key, sep, text = str(item).partition("=")
        key = key.strip()
        if not sep or not key.isidentifier():
            raise InvalidInput(f"--bus-option {item!r}: expected KEY=VALUE, e.g. port=43113")
        value: object = text.strip()
        if value.lower() in ("true", "false"):
            value = value.lower() == "true"
        else:
            for kind in (int, float):
                try:
                    value = kind(text.strip())
                    break
                except ValueError:
                    pass
        options[key] = value
    return options


def _check_can_bus(settings) -> None:
    """--interface/--channel (and the bus options) must open now: python-can opens and closes the
    bus once (exit 2 with python-can's reason otherwise, before anything runs)."""
    from cosim.results.exits import InvalidInput
    from cosim.execution.can_side import BusOpenError, open_can_bus

    try:
        open_can_bus(settings).shutdown()
    except BusOpenError as exc:
        raise InvalidInput(str(exc)) from None


def _check_address_free(channel: str) -> None:
    """--channel must be usable now: the udpcycle interface opens and closes it once (exit 2
    with its message otherwise, before anything runs)."""
    from cosim.results.exits import InvalidInput
    from fieldbus.udpcycle import UdpCycleBus, UdpCycleError

    try:
        UdpCycleBus(channel=channel).shutdown()
    except UdpCycleError as exc:
        raise InvalidInput(f"--channel {channel!r}: {exc}; expected a free UDP address of this machine") from None


def _warn_cycle_time_mismatch(hil: dict) -> None:
    """One line per served run whose controller ran at another cycle time (docs/how-to/served_cell.md)."""
    for label, report in hil.items():
        found = report.get("cycle_time_mismatch") if isinstance(report, dict) else None
        if found:
            estimate = found.get("controller_cycle_time_s_estimate")
            print(f"warning: {label}: cycle-time mismatch from cell cycle {found['first_cycle']} on "
                  f"({found['blocks']} of {found['blocks_judged']} blocks): the controller's cycle is about "
                  f"{'?' if estimate is None else f'{estimate * 1e3:.4g}'} ms, the cell's "
                  f"{found['cell_cycle_time_s'] * 1e3:.4g} ms (hil_endpoint.json cycle_time_s); its frames were "
                  f"lost cycles for the threshold counters (summary.json hil.{label})", file=sys.stderr)


def _report_losses(hil: dict) -> None:
    """One line per served run: the cycles lost (their runs, the longest) and the drives' fault
    reactions (loss-of-SoC/PReq trips), whatever the thresholds let through."""
    for label, report in hil.items():
        if not isinstance(report, dict) or "lost_cycles_total" not in report:
            continue
        runs = report.get("lost_cycle_runs") or {}
        trips = [f for f in report.get("fault_reactions", []) if f.get("event") == "fault_reaction"]
        first = f"; first at cycle {trips[0]['cycle']} (t = {trips[0]['time_s']:.4g} s)" if trips else ""
        print(f"{label}: {report['lost_cycles_total']} lost cycles in {runs.get('count', 0)} runs (longest "
              f"{runs.get('longest', 0)}), {report.get('fault_reactions_total', len(trips))} fault reaction "
              f"events{first} (summary.json hil.{label})", file=sys.stderr)


def _warn_transport_faults(hil: dict) -> None:
    """One line per served run that dropped datagrams: malformed or truncated ones, foreign
    ones (from a sender other than the controller) and duplicates."""
    for label, report in hil.items():
        transport = report.get("transport") if isinstance(report, dict) else None
        if not transport:
            continue
        found = {k: transport.get(k, 0) for k in ("malformed", "foreign", "duplicates")}
        if any(found.values()):
            counts = ", ".join(f"{v} {k}" for k, v in found.items() if v)
            print(f"warning: {label}: datagrams dropped by the cell: {counts} (summary.json "
                  f"hil.{label}.transport; docs/how-to/served_cell.md)", file=sys.stderr)


def _check_cpu_and_hosts(cpu: str | None, accept_from, peer: str | None = None) -> None:
    """--cpu names a CPU this process may use, --accept-from and --peer hosts that resolve (exit 2
    before anything runs; at run time the first would be ignored and the others would fail the run
    after the set-up)."""
    import os
    import socket

    from cosim.results.exits import InvalidInput

    if cpu not in (None, "auto", "none") and hasattr(os, "sched_getaffinity"):
        usable = sorted(os.sched_getaffinity(0))
        if not (cpu.strip().isdigit() and int(cpu) in usable):
            raise InvalidInput(f"--cpu: expected 'auto', 'none' or a CPU this process may use {usable}, got {cpu!r}")
    hosts = []  # (option, host, what the option expects)
    for item in accept_from or ():
        host, sep, port = str(item).rpartition(":")
        hosts.append(("--accept-from", host if sep and port.isdigit() else str(item),
                      "hosts or host:port of this network"))
    if peer is not None:
        hosts.append((f"--peer {peer!r}", str(peer).rpartition(":")[0], "the controller's host:port"))
    for option, host, expected in hosts:
        try:
            socket.gethostbyname(host)
        except OSError as exc:
            raise InvalidInput(f"{option}: cannot resolve {host!r} ({exc}); expected {expected}") from None
