"""`vprsnn-export demo`: the whole chain on the embedded synthetic route, no download needed.

train -> quantise (8 bits, per-neuron scales, deployed calibration) -> export (NIR,
Loihi-style, ONNX) and read every file back -> verify against float -> report.

The demo trains the default configuration (DoG ON/OFF inputs, T = 300, 60 epochs, 400 neurons): about a
minute on one CPU core. Torch is limited to one CPU thread unless OMP_NUM_THREADS is
set (see :mod:`vprsnn_export.threads`). ``--quick`` (for the tests) applies a
tiny profile, which is written into the checkpoint's config and printed.

It shows every width it computes (8, 4 and 2 bits), each with its paired verdict (docs/verify.md):
holds, undecided (the route's queries cannot tell it from float) or fails. The first line of its
output says what a user should conclude; the verdict and exit code agree with the report (its HTML
"Verdict" line): 1 when a width fails, else 0. The checks behind a verdict are named on the console
with their interval, in percentage points like the report; every command it suggests runs as printed.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from shlex import quote

from ..config import Config
from ..data.dataset import load_dataset
from ..data.preprocess import CHANNELS
from ..errors import EXIT_CHECK_FAILED
from ..export.model import DEFAULT_BITS
from ..io.checkpoint import checkpoint_sha256, save_checkpoint
from ..network.modules import module_count
from ..readout.sequence import SequenceOptions
from ..readout.strategies import SEQUENCE_STRATEGY
from ..runtime.results import BitsResult, VerifiedRun, VerifyReport
from ._common import RESULT_COLUMNS, add_runtime_options, format_table, integer

DEMO_DATA = "synthetic"
DEMO_PLACES = 240
DEMO_REFERENCE = "summer"
DEMO_QUERY = "winter"
DEMO_KS = (1, 3, 5)
#: The widths the demo computes and shows, each with its verdict (none is left out).
DEMO_BITS = DEFAULT_BITS
#: Config overrides of the demo: the default network as an ensemble of 4 modules of 60 places
#: (the route is a whole route in miniature: each module learns its region side by side).
DEMO_PROFILE: dict = {"train.module_size": 60}
#: --quick (tests): a tiny ensemble of two modules on a short route.
QUICK_PROFILE = {"encoder.timesteps": 40, "train.epochs": 2, "network.n_neurons": 48, "train.module_size": 8}
QUICK_PLACES = 16
SUMMARY_COLUMNS = (
    ("bits", "bits"),
    ("verdict", "verdict"),
    ("exports", "NIR / Loihi / ONNX read back"),
    ("accuracy", "acc W+Prob k=1 %"),
    ("r_at_100p", "R@100P W+Prob k=5 %"),
    ("delta", "R@100P k=5 Δ vs float (pts)"),
    ("winner", "same winner %"),
    ("module", "weakest module (k=5 Δ pts)"),
    ("paired", "paired checks"),
)
#: Checks named per width under the table (the report lists them all).
SHOWN_CHECKS = 3


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "demo", help="train, quantise, export, verify and report on the embedded synthetic route"
    )
    parser.add_argument(
        "--out",
        default="vprsnn-demo",
        help="output folder (default: %(default)s; its files are regenerated on each run)",
    )
    parser.add_argument("--seed", type=integer, default=Config().seed, help="seed")
    parser.add_argument("--quick", action="store_true", help=argparse.SUPPRESS)  # tiny run for the tests
    add_runtime_options(parser)
    parser.set_defaults(handler=run)


def demo_config(seed: int, quick: bool = False) -> Config:
    """The default configuration with the demo profile (or the test profile) applied."""
    return Config().replace(**{**(QUICK_PROFILE if quick else DEMO_PROFILE), "seed": seed})


def profile_text(cfg: Config, n_places: int, profile: dict) -> str:
    """What the demo trains: inputs, T, epochs and the ensemble's modules, and any profile changes."""
    inputs = CHANNELS.get(cfg.preprocess.channels).label
    modules = module_count(n_places, cfg.train.module_size)
    size = cfg.train.module_size or n_places
    text = (
        f"{inputs} inputs, T = {cfg.encoder.timesteps}, {cfg.train.epochs} epochs, an ensemble of {modules} "
        f"modules of {size} places x {cfg.network.n_neurons} neurons"
    )
    tiny = {k: v for k, v in profile.items() if k != "train.module_size"}
    if tiny:
        text += " (test profile: " + ", ".join(f"{k} = {v}" for k, v in tiny.items()) + ")"
    return text


def failed_checks(result: BitsResult) -> list[str]:
    """The checks behind a width's verdict (none when it holds): differing exports, missed point limits, and
    the paired checks that fail or are undecided, with their difference and interval in points."""
    from ..runtime.report.blocks import POINT_CHECKS
    from ..runtime.report.labels import paired_cells, points

    failed = [f"{c.what}: {points(c.check, c.value)} (limit {points(c.check, c.applied_limit)})"
              for c in result.tolerance_checks if not c.passed and c.check in POINT_CHECKS]  # fmt: skip
    if not result.cross_implementation.passed:
        failed.insert(0, f"{result.cross_implementation.n_failed} cross-implementation differences")
    for verdict in ("fails", "undecided"):
        for check in result.paired:
            if check.verdict == verdict:
                cells = paired_cells(check)
                failed.append(
                    f"{cells['metric']} {cells['readout']} {cells['difference']} pts, interval {cells['interval']} "
                    f"({verdict}, limit {cells['limit']})"
                )
    return failed


def reasons(result: BitsResult) -> str:
    """One console line per width: its verdict and the first checks behind it."""
    failed = failed_checks(result)
    more = f"; {len(failed) - SHOWN_CHECKS} more in the report" if len(failed) > SHOWN_CHECKS else ""
    return f"  {result.bits} bits {result.verdict}: " + ("; ".join(failed[:SHOWN_CHECKS]) + more if failed else "-")


def conclusion(report: VerifyReport) -> str:
    """The first line a user reads: which widths keep the float network's recognition, which cannot be told
    from it on this route, which lose it."""
    verdicts = {r.bits: r.verdict for r in report.runs[0].bits}
    parts = [
        f"{'/'.join(str(b) for b in widths)} bits {label}"
        for verdict, label in (
            ("holds", "keep the float network's recognition within every tolerance (paired 95 % intervals)"),
            ("undecided", "cannot be told from float on this route's queries (undecided: more queries would decide)"),
            ("fails", "lose recognition beyond a tolerance"),
        )
        if (widths := [b for b, v in verdicts.items() if v == verdict])
    ]
    deploy = [b for b, v in verdicts.items() if v == "holds"]
    advice = f"deploy at {min(deploy)} bits or more" if deploy else "no width is shown to hold"
    return (
        "Conclusion: "
        + "; ".join(parts)
        + f". So: {advice}; every exported file matches the simulator"
        + ("" if all(r.cross_implementation.passed for r in report.runs[0].bits) else " (NOT: see the differences)")
    )


def hints(out: Path, data: str) -> list[str]:
    """Commands a user can run next, exactly as printed (a test runs them)."""
    bits = ",".join(map(str, DEMO_BITS))
    ks = ",".join(map(str, DEMO_KS))
    return [
        f"vprsnn-export verify {quote(str(out / 'float.npz'))} --data {data} --query {DEMO_QUERY} --bits {bits} "
        f"--k {ks} --report {quote(str(out / 'verify'))}",
        f"vprsnn-export report {quote(str(out / 'report'))}",
    ]


def demo_table_rows(run_result: VerifiedRun) -> list[dict]:
    from ..runtime.report.labels import cross_counts, verdict_counts

    top = max(DEMO_KS)
    rows = []
    for result in run_result.bits:
        cross = result.cross_implementation
        wprob, aggregated = result.row(SEQUENCE_STRATEGY, 1), result.row(SEQUENCE_STRATEGY, top)
        delta = 0.0 if aggregated.delta is None else aggregated.delta.r_at_100p
        weakest = min(result.modules, key=lambda m: (m.delta_k, m.winner_agreement), default=None)
        rows.append(
            {
                "bits": result.bits,
                "verdict": result.verdict,
                "paired": verdict_counts(result.paired) or "-",
                "exports": cross_counts([cross]) + ("" if cross.passed else f", {cross.n_failed} DIFFER"),
                "accuracy": f"{100 * wprob.accuracy:.1f}",
                "r_at_100p": f"{100 * aggregated.r_at_100p:.1f}",
                "delta": f"{100 * delta:+.1f}",
                "winner": f"{100 * result.spike_level.winner_agreement:.1f}",
                "module": "-" if weakest is None else f"{weakest.module} ({100 * weakest.delta_k:+.1f})",
            }
        )
    return rows


def run(args: argparse.Namespace) -> int:
    from ..device import resolve_device
    from ..runtime.deployment import QuantiseOptions
    from ..runtime.report import write_report
    from ..runtime.verify import VerifyOptions, build_report, verify_checkpoint
    from ..trainer.pipeline import train_and_calibrate

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    threads = args.threads
    cfg = demo_config(args.seed, args.quick)
    device = resolve_device(args.device)
    progress = not args.quiet
    started = time.perf_counter()
    data = f"{DEMO_DATA}:{QUICK_PLACES if args.quick else DEMO_PLACES}"
    profile = QUICK_PROFILE if args.quick else DEMO_PROFILE

    def say(message: str) -> None:
        if progress:
            print(f"[demo {time.perf_counter() - started:5.1f} s] {message}", file=sys.stderr)

    dataset = load_dataset(data, [DEMO_REFERENCE, DEMO_QUERY], cfg.preprocess, progress=progress)
    say(
        f"synthetic route ({data}): {dataset.n_places} places, reference {DEMO_REFERENCE}, query {DEMO_QUERY}; "
        f"{threads} CPU thread(s) (--threads N to change)"
    )
    say(profile_text(cfg, dataset.n_places, profile))
    ckpt = train_and_calibrate(
        dataset, [DEMO_REFERENCE], cfg, device=device, progress=progress, selection={"subset": None, "places": None}
    )
    ckpt_path = save_checkpoint(out / "float.npz", ckpt)
    say(f"1/4 trained {cfg.train.epochs} epochs -> {ckpt_path}")
    quantise = QuantiseOptions()  # per-neuron max-abs scales, deployed calibration: quantize's defaults
    options = VerifyOptions(readout=SequenceOptions(ks=DEMO_KS), bits=DEMO_BITS, quantise=quantise)
    say(
        "each bit width gets a verdict (docs/verify.md): holds (every paired interval inside its tolerance), "
        "undecided (an interval straddles its tolerance: too few queries to tell), fails (one lies beyond it: "
        "exit code 1)"
    )
    say(
        f"2/4 quantising {', '.join(map(str, DEMO_BITS))} bits ({'per-neuron' if quantise.per_neuron else 'per-tensor'}"
        f", {quantise.calibration} calibration) and exporting NIR, Loihi-style and ONNX; every file is read back and run"
    )
    result = verify_checkpoint(
        ckpt,
        checkpoint_sha256(ckpt_path),
        dataset.traversal(DEMO_QUERY),
        dataset.place_ids,
        DEMO_QUERY,
        options,
        reference_images={DEMO_REFERENCE: dataset.traversal(DEMO_REFERENCE)},
        export_dir=out / "deploy",
        device=device,
        progress=progress,
        label="demo",
        checkpoint=str(ckpt_path),
    )
    say(f"3/4 verified against float on the same {result.n_queries} query presentations")
    settings = {
        **options.to_dict(cfg),
        "query": DEMO_QUERY,
        "data": data,
        "subset": None,
        "places": None,
        "seeds": None,
        "checkpoints": [str(ckpt_path)],
        "device": args.device,
        "demo_profile": profile,
    }
    command = ["vprsnn-export", "demo", "--out", str(out), "--seed", str(args.seed)] + (
        ["--quick"] if args.quick else []
    )
    report = build_report([result], settings, command=command, seconds=time.perf_counter() - started)
    written = write_report(report, out / "report")
    say(f"4/4 report written ({written['json']})")
    print(conclusion(report))
    print(f"\nfloat network ({profile_text(cfg, dataset.n_places, profile)}):")
    print(format_table([row.to_dict() for row in result.float.metrics], RESULT_COLUMNS))
    print("\nquantised and deployed vs float (paired verdicts and tolerances: docs/verify.md):")
    print(format_table(demo_table_rows(result), SUMMARY_COLUMNS))
    print("\n".join(reasons(r) for r in result.bits))
    exact = all(r.cross_implementation.passed for r in result.bits)
    print(
        f"\nexports: {out / 'deploy'}   cross-implementation: {'all exact' if exact else 'DIFFERENCES FOUND'}   "
        f"time: {time.perf_counter() - started:.0f} s"
    )
    print("next:\n" + "\n".join(f"  $ {hint}" for hint in hints(out, data)))
    print(f"report: {written['html'].resolve()}")
    code = EXIT_CHECK_FAILED if report.verdict == "fails" else 0
    print(f"Verdict: {report.verdict.upper()} (as in the report; exit code {code})")
    return code
