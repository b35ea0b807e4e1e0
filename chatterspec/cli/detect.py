"""``chatterspec detect NAME``: spectral fault detection on one catalogue scenario."""

from __future__ import annotations

import argparse
import sys

from ._common import Outputs, add_detector_args, add_live_args, check_record_path, print_json


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "detect",
        help="detect a fault in a catalogue scenario from its chattering spectrum",
        description="Simulate NAME, run the auxiliary SVSF, compare the chattering periodogram with "
        "chi-squared thresholds and, for multi-segment scenarios, localize the fault with the STFT.",
    )
    p.add_argument("name", metavar="NAME", help="scenario name (see 'chatterspec scenarios')")
    add_detector_args(p)
    add_live_args(p)
    p.add_argument(
        "--calibration",
        metavar="FILE",
        help="use the empirical family-wise threshold of a calibration file written by "
        "'chatterspec calibrate --out FILE' (refused if it was made for another model or length)",
    )
    p.add_argument("--json", action="store_true", help="print one JSON document on stdout")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..detection.detect import detect_record
    from ..detection.pipeline import chattering_record
    from ..plants.scenarios import scenario
    from ..plants.simulate import simulate

    check_record_path(args.record)
    sc = scenario(args.name)
    sim = simulate(sc, args.runs, args.seed)  # simulated once: detection and recording
    record = chattering_record(sc.nominal, sim.z, sim.u, scenario=sc)
    threshold = args.threshold
    if args.calibration:
        from ..studies.calibration import load_calibration

        cal = load_calibration(args.calibration, sc.nominal, record.n_samples)
        threshold = cal.threshold("family-wise")
    report = detect_record(record, args.alpha, threshold, args.correction)
    doc = report.to_dict()
    doc["seed"] = args.seed
    doc["fault_intervals_true"] = [list(iv) for iv in sc.fault_intervals]
    if args.record or args.live:
        from ..online.drivers import record_detection
        from ..online.monitor import MonitorSettings

        settings = MonitorSettings(alpha=args.alpha, correction=args.correction)
        outputs = Outputs()
        summary = outputs.write(
            "--record", args.record, record_detection, sim, settings, path=args.record, live=args.live
        )
        if summary is not None:
            doc["recording"] = summary.to_dict()
            for note in summary.notes:
                print(note, file=sys.stderr)
    if args.json:
        print_json(doc)
    else:
        print_report(doc)
    if args.record or args.live:
        outputs.finish()  # a failed recording: the result above is printed first
    return 0


def print_report(doc: dict) -> None:
    th = doc["threshold"]
    runs = doc["runs"]
    print(f"scenario {doc['scenario']}  runs {runs}  seed {doc['seed']}")
    print(f"threshold: {th['description']}")
    head = f"{'channel':<10} {'detected':<9} {'peak Hz':>8} {'peak ratio':>11} {'excess power':>13}"
    if runs > 1:
        head += f" {'rate':>6}"
        print(f"averaged spectrum: {doc['averaged_threshold']['description']}")
        print("(verdicts of the averaged spectrum; rate = fraction of single runs detected)")
    print(head)
    for c in doc["channels"]:
        line = (
            f"{c['channel']:<10} {'YES' if c['detected'] else 'no':<9} {c['peak_hz']:8.2f} "
            f"{c['peak_ratio']:11.3f} {c['excess_power']:13.4f}"
        )
        if runs > 1:
            line += f" {c['detection_rate']:6.3f}"
        print(line)
    print(f"fault detected: {'YES' if doc['detected'] else 'no'}")
    if "intervals" in doc:
        ivs = [iv for iv in doc["intervals"] if iv["channel"] == "any"]
        shown = ", ".join(f"[{iv['onset_s']:.1f}, {iv['offset_s']:.1f}] s" for iv in ivs) or "none"
        print(f"STFT intervals (any channel): {shown}")
        true = ", ".join(f"[{a:g}, {b:g}) s" for a, b in doc["fault_intervals_true"]) or "none"
        print(f"true fault windows: {true}")
    if "recording" in doc and doc["recording"]["recording"]:
        rrd = doc["recording"]["recording"]
        print(f"recording: {rrd}  (open with: chatterspec replay {rrd})")
