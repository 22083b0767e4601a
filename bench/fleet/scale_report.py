"""The tables of ``bench/fleet/scale.py``: rates, CPU per transaction and memory per device from each size's
figures (one child process per size), printed side by side."""

from __future__ import annotations

import argparse
import os
import sys

from starterbus.transports.modbus.codec.timing import silent_interval

DEVICENET_BITRATE = 500000


def _f(value: object) -> float:
    assert isinstance(value, (int, float))
    return float(value)


def _lines(r: dict[str, object]) -> list[dict[str, object]]:
    lines = r["lines"]
    assert isinstance(lines, list)
    return lines


def derived(r: dict[str, object]) -> dict[str, float]:
    """Rates, CPU per transaction (whole process and per thread group) and memory per device of one size."""
    n, window, rounds = _f(r["devices"]), _f(r["window_s"]), _f(r["rounds"])
    tx, cpu = _f(r["transactions"]), _f(r["cpu_s"])
    groups = r["threads_cpu_s"]
    assert isinstance(groups, dict)
    rtu_tx = sum(_f(e["transactions"]) for e in _lines(r) if e["kind"] == "modbus")
    dnet_tx = sum(_f(e["transactions"]) for e in _lines(r) if e["kind"] == "devicenet")
    grown_kib = _f(r["peak_rss_kib"]) - _f(r["rss_base_kib"])

    def per(group: str, count: float) -> float:
        return 1e6 * float(groups.get(group, 0.0)) / count if count else 0.0

    def cores(group: str) -> float:
        return float(groups.get(group, 0.0)) / window

    return {
        "rounds_per_s": rounds / window,
        "ms_per_round": 1000 * window / rounds,
        "tx_per_s": tx / window,
        "cpu_us_per_tx": 1e6 * cpu / tx if tx else 0.0,
        "cores": cpu / window,
        "sim_share": (float(groups.get("rtu_sims", 0.0)) + float(groups.get("dnet_sims", 0.0))) / cpu if cpu else 0.0,
        "peak_mib": _f(r["peak_rss_kib"]) / 1024,
        "kib_per_device": grown_kib / n,
        "rtu_tx_per_s": rtu_tx / window,
        "dnet_tx_per_s": dnet_tx / window,
        "rtu_worker_us": per("rtu_workers", rtu_tx),
        "rtu_sim_us": per("rtu_sims", rtu_tx),
        "dnet_worker_us": per("dnet_workers", dnet_tx),
        "scanner_cores": cores("scanners"),
        "dnet_sim_cores": cores("dnet_sims"),
        "other_cores": cores("other"),
    }


def report(results: list[dict[str, object]], args: argparse.Namespace) -> None:
    print()
    print(
        f"{'devices':>7} {'per line: rtu | dnet':>27} {'start s':>7} {'rounds':>6} {'window s':>8} {'rounds/s':>8} "
        f"{'ms/round':>8} {'tx/s':>6} {'CPU us/tx':>9} {'cores':>5} {'sims':>4} {'peak MiB':>8} {'KiB/dev':>7} "
        f"{'errors':>6}"
    )
    for r in results:
        d = derived(r)
        rtu = "/".join(f"{_f(e['devices']):.0f}" for e in _lines(r) if e["kind"] == "modbus")
        dnet = "/".join(f"{_f(e['devices']):.0f}" for e in _lines(r) if e["kind"] == "devicenet")
        print(
            f"{_f(r['devices']):7.0f} {rtu + ' | ' + dnet:>27} {_f(r['startup_online_s']):7.1f} {_f(r['rounds']):6.0f} "
            f"{_f(r['window_s']):8.2f} {d['rounds_per_s']:8.2f} {d['ms_per_round']:8.1f} {d['tx_per_s']:6.0f} "
            f"{d['cpu_us_per_tx']:9.0f} {d['cores']:5.2f} {d['sim_share']:4.0%} {d['peak_mib']:8.1f} "
            f"{d['kib_per_device']:7.1f} {_f(r['errors']):6.0f}"
        )
        if r.get("tracemalloc_peak_kib") is not None:
            print(
                f"{'':7} tracemalloc peak (Python heap, start-up included): "
                f"{_f(r['tracemalloc_peak_kib']) / 1024:.1f} MiB"
            )
        if r.get("last_error"):
            print(f"{'':7} {_f(r['errors_total']):.0f} errors in the whole run; last: {r['last_error']}")

    print("\nCPU by thread group in the window (us per transaction of that kind, or cores = CPU s / wall s):")
    print(
        f"{'devices':>7} {'rtu tx/s':>8} {'rtu worker us/tx':>16} {'rtu sim us/tx':>13} {'dnet tx/s':>9} "
        f"{'dnet worker us/tx':>17} {'scanners cores':>14} {'dnet sims cores':>15} {'other cores':>11}"
    )
    for r in results:
        d = derived(r)
        print(
            f"{_f(r['devices']):7.0f} {d['rtu_tx_per_s']:8.0f} {d['rtu_worker_us']:16.0f} {d['rtu_sim_us']:13.0f} "
            f"{d['dnet_tx_per_s']:9.0f} {d['dnet_worker_us']:17.0f} {d['scanner_cores']:14.2f} "
            f"{d['dnet_sim_cores']:15.2f} {d['other_cores']:11.2f}"
        )

    if len(results) > 1:
        base = results[0]
        b = derived(base)

        def ratio(x: float, y: float) -> str:
            return f"{x / y:.2f}" if y else "-"

        print(f"\ngrowth against N={_f(base['devices']):.0f} (x; 'x devices' is the linear reference):")
        print(f"{'devices':>7} {'x devices':>9} {'ms/round':>8} {'CPU/tx':>8} {'rtu worker/tx':>13} {'KiB/dev':>8}")
        for r in results:
            d = derived(r)
            print(
                f"{_f(r['devices']):7.0f} {_f(r['devices']) / _f(base['devices']):9.1f} "
                f"{ratio(d['ms_per_round'], b['ms_per_round']):>8} {ratio(d['cpu_us_per_tx'], b['cpu_us_per_tx']):>8} "
                f"{ratio(d['rtu_worker_us'], b['rtu_worker_us']):>13} "
                f"{ratio(d['kib_per_device'], b['kib_per_device']):>8}"
            )

    silence = silent_interval(args.baudrate)
    print(
        "\nper line: ms/round = window / that line's rounds; '% fleet' = its share of the fleet round (the slowest "
        f"line sets it);\nModbus floor per round: pty = 2 x {silence * 1000:.3f} ms of silence per request (a pty "
        f"moves the bytes at once), wire = silences + 11-bit characters at {args.baudrate} baud;\n"
        f"DeviceNet floor = one CAN scan of the bus at {DEVICENET_BITRATE // 1000} kbit/s (the scanner scans every "
        "20 ms by itself; a poll reads its latest inputs)."
    )
    for r in results:
        d = derived(r)
        window = _f(r["window_s"])
        print(f"\nN={_f(r['devices']):.0f}:")
        print(
            f"  {'line':7} {'devices':>7} {'rounds':>7} {'ms/round':>9} {'% fleet':>7} {'worker us/tx':>12} "
            f"{'on the wire':>14} {'pty floor ms':>12} {'% of round':>10} {'wire floor ms':>13}"
        )
        slowest = max(_lines(r), key=lambda e: window / _f(e["rounds"]))
        for e in _lines(r):
            ms = 1000 * window / _f(e["rounds"])
            tx = _f(e["transactions"])
            worker = 1e6 * _f(e["worker_cpu_s"]) / tx if tx else 0.0
            unit = "req/s" if e["kind"] == "modbus" else "scans/s"
            if "floor_pty_s" in e:
                pty = f"{1000 * _f(e['floor_pty_s']):12.1f} {1000 * _f(e['floor_pty_s']) / ms:10.0%}"
            else:
                pty = f"{'-':>12} {'-':>10}"
            print(
                f"  {e['line']!s:7} {_f(e['devices']):7.0f} {_f(e['rounds']):7.1f} {ms:9.1f} "
                f"{ms / d['ms_per_round']:7.0%} {worker:12.0f} {_f(e['wire']) / window:6.0f} {unit:7} {pty} "
                f"{1000 * _f(e['floor_wire_s']):13.1f}{' <- slowest' if e is slowest else ''}"
            )
        ms = 1000 * window / _f(slowest["rounds"])
        line = f"  limit: {slowest['line']} ({slowest['kind']}, {_f(slowest['devices']):.0f} devices) sets the round"
        if "floor_pty_s" in slowest:
            floor = 1000 * _f(slowest["floor_pty_s"])
            line += (
                f"; {floor / ms:.0%} of its {ms:.0f} ms is the RTU silent interval, {1 - floor / ms:.0%} is time in "
                f"Python (poller, client, slave simulator, waiting for the GIL); on a real {args.baudrate} baud wire "
                f"the same line needs at least {_f(slowest['floor_wire_s']):.2f} s per round"
            )
        print(line)
    print(
        "\nNote: the simulators (Modbus slaves, DeviceNet nodes), the DeviceNet scanners and the poller's bus workers "
        "all run in this one Python\nprocess: they share one GIL and the machine's "
        f"{os.cpu_count()} cores, so 'CPU us/tx' (process CPU / FleetPoller.transactions()) includes the simulators' "
        "work\n('sims' = their share of the process CPU). 'cores' near 1.0 means the GIL is saturated: one thread "
        "runs Python at a time,\nand a thread woken by I/O (a Modbus answer, a slave's silence timer) may wait up to "
        f"the switch interval ({sys.getswitchinterval() * 1000:g} ms) for it.\nPeak MiB = ru_maxrss of the child "
        "process (start-up included); KiB/dev = (peak - RSS after imports) / devices."
    )
