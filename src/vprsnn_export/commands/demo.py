"""`vprsnn-export demo`: the whole chain on the embedded synthetic route, no download needed, decided in minutes.

train -> quantise (8, 4, 2 bits) -> export and read every file back -> verify against float -> report. It exits 0
when the chain ran as intended, whatever a width's verdict, and 1 only when an exported file differs.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from shlex import quote

from ..config import Config, preset
from ..data.dataset import load_dataset
from ..data.preprocess import CHANNELS
from ..errors import EXIT_CHECK_FAILED
from ..export.model import DEFAULT_BITS
from ..io.checkpoint import checkpoint_sha256, save_checkpoint
from ..network.modules import module_count
from ..readout.sequence import SequenceOptions
from ..runtime.results import BitsResult, VerifyReport
from ._common import RESULT_COLUMNS, add_runtime_options, format_table, integer

DEMO_DATA = "synthetic"
DEMO_PLACES = 600
DEMO_REFERENCE = "summer"
DEMO_QUERY = "winter"
DEMO_KS = (1, 3, 5)
#: The widths the demo computes and shows, each with its verdict (none is left out).
DEMO_BITS = DEFAULT_BITS
DEMO_PRESET = "lean"
#: Config overrides of the demo on top of the lean preset: 10 epochs (60 is the default) of 6 modules of 100 places.
DEMO_PROFILE: dict = {"train.epochs": 10}
#: --quick (tests): a tiny ensemble of two modules on a short route.
QUICK_PROFILE = {
    "encoder.timesteps": 40,
    "train.timesteps": 40,
    "train.epochs": 2,
    "network.n_neurons": 48,
    "train.module_size": 8,
}
QUICK_PLACES = 16
SUMMARY_COLUMNS = (
    ("bits", "bits"),
    ("verdict", "verdict"),
    ("paired", "paired checks"),
    ("exports", "NIR / Loihi / ONNX read back"),
    ("winner", "same winner %"),
)
#: What each verdict means, in one line each (docs/verify.md says it at length).
MEANINGS = (
    ("holds", "every paired 95 % interval lies inside its tolerance: deploy at this width"),
    ("fails", "an interval lies wholly beyond its tolerance (or a file differs): this width loses recognition"),
    ("undecided", "an interval straddles its tolerance: more queries than the route has would decide"),
)


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


def profile_text(cfg: Config, n_places: int, profile: dict) -> str:
    """What the demo trains: inputs, T, epochs and the ensemble's modules, and any profile changes."""
    inputs = CHANNELS.get(cfg.preprocess.channels).label
    modules = module_count(n_places, cfg.train.module_size)
    size = cfg.train.module_size or n_places
    return (
        f"--preset {DEMO_PRESET} ({inputs} inputs, T = {cfg.train.timesteps} to learn and {cfg.encoder.timesteps} to "
        f"recognise), {cfg.train.epochs} epochs, an ensemble of {modules} modules of {size} places x "
        f"{cfg.network.n_neurons} neurons; profile: " + ", ".join(f"{k} = {v}" for k, v in profile.items())
    )


def deciding_check(result: BitsResult) -> str:
    """The one check that decides a width's verdict, with its interval and limit in points."""
    from ..runtime.report.blocks import failed_points
    from ..runtime.report.labels import paired_cells

    judged = [c for c in result.paired if c.limit is not None and c.verdict in ("holds", "fails", "undecided")]
    others = failed_points(result, ":")
    if result.verdict == "fails" and others:
        return "; ".join(others)
    if not judged:
        return "no paired check judged"
    if result.verdict == "fails":
        check = min((c for c in judged if c.verdict == "fails"), key=lambda c: c.high + (c.limit or 0))
        tail = "the whole interval lies beyond the drop limit"
    elif result.verdict == "undecided":
        check = max((c for c in judged if c.verdict == "undecided"), key=lambda c: c.queries_to_decide or 0)
        need = f"~{check.queries_to_decide} queries would decide it" if check.queries_to_decide else "on the limit"
        tail = f"straddles the drop limit: {need} (the route has {check.n_queries})"
    else:
        check = min(judged, key=lambda c: c.low + (c.limit or 0))
        tail = "the closest check to its limit, inside it"
    cells = paired_cells(check)
    return (
        f"{cells['readout']} {cells['metric']} {cells['difference']} pts {cells['interval']} "
        f"(drop limit {cells['limit']}): {tail}"
    )


def conclusion(report: VerifyReport) -> list[str]:
    """A line naming every width's verdict and what to deploy, then a line per width with its deciding check."""
    results = report.runs[0].bits
    verdicts = {r.bits: r.verdict for r in results}
    parts = [
        f"{'/'.join(str(b) for b in widths)} bits {verdict}"
        for verdict in ("holds", "fails", "undecided")
        if (widths := [b for b, v in verdicts.items() if v == verdict])
    ]
    deploy = [b for b, v in verdicts.items() if v == "holds"]
    advice = f"deploy at {min(deploy)} bits or more" if deploy else "no width is shown to hold"
    lines = [f"Conclusion: {', '.join(parts)} on this route's {report.runs[0].n_queries} queries. So: {advice}."]
    width = max(len(r.verdict) for r in results)
    lines += [f"  {r.bits} bits {r.verdict.upper():<{width}}  {deciding_check(r)}" for r in results]
    return lines


def hints(out: Path, data: str) -> list[str]:
    """Commands that rerun a step of the demo, exactly as printed (a test runs them)."""
    return [
        f"vprsnn-export verify {quote(str(out / 'float.npz'))} --data {data} --query {DEMO_QUERY} --bits "
        f"{','.join(map(str, DEMO_BITS))} --k {','.join(map(str, DEMO_KS))} --report {quote(str(out / 'verify'))}",
        f"vprsnn-export report {quote(str(out / 'report'))}",
    ]


#: The next three commands on a user's own data (docs/data.md: a folder per traversal with a ground-truth file).
OWN_DATA = (
    "vprsnn-export train --data ROUTE/ --reference REFERENCE --preset lean --out net.npz",
    "vprsnn-export verify net.npz --data ROUTE/ --query QUERY --bits 8,4,2 --report verify/",
    "vprsnn-export localize verify/deploy/8bit/model.npz --frames QUERY_FRAMES/ --k 5",
)


def run(args: argparse.Namespace) -> int:
    from ..device import resolve_device
    from ..export.quantize import QuantiseOptions
    from ..runtime.report import write_report
    from ..runtime.report.labels import cross_counts, verdict_cells
    from ..runtime.verify import Runtime, VerifiedNetwork, VerifyOptions, build_report, verify_checkpoint
    from ..trainer.pipeline import train_and_calibrate

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    profile = QUICK_PROFILE if args.quick else DEMO_PROFILE
    cfg = preset(DEMO_PRESET).replace(**{**profile, "seed": args.seed})  # the lean preset with the profile applied
    device = resolve_device(args.device)
    progress = not args.quiet
    started = time.perf_counter()
    data = f"{DEMO_DATA}:{QUICK_PLACES if args.quick else DEMO_PLACES}"

    def say(message: str) -> None:
        if progress:
            print(f"[demo {time.perf_counter() - started:5.1f} s] {message}", file=sys.stderr)

    dataset = load_dataset(data, [DEMO_REFERENCE, DEMO_QUERY], cfg.preprocess, progress=progress)
    say(
        f"synthetic route ({data}): {dataset.n_places} places, reference {DEMO_REFERENCE}, query {DEMO_QUERY}; "
        f"{args.threads} CPU thread(s) (--threads N to change)"
    )
    say(profile_text(cfg, dataset.n_places, profile))
    ckpt = train_and_calibrate(
        dataset, [DEMO_REFERENCE], cfg, device=device, progress=progress, selection={"subset": None, "places": None}
    )
    ckpt_path = save_checkpoint(out / "float.npz", ckpt)
    trained = time.perf_counter() - started
    say(f"1/4 trained {cfg.train.epochs} epochs -> {ckpt_path}")
    quantise = QuantiseOptions()  # per-neuron max-abs scales, deployed calibration: quantize's defaults
    options = VerifyOptions(readout=SequenceOptions(ks=DEMO_KS), bits=DEMO_BITS, quantise=quantise)
    say(
        f"2/4 quantising {', '.join(map(str, DEMO_BITS))} bits ({'per-neuron' if quantise.per_neuron else 'per-tensor'}"
        f", {quantise.calibration} calibration) and exporting NIR, Loihi-style and ONNX; every file is read back and run"
    )
    network = VerifiedNetwork(
        ckpt, checkpoint_sha256(ckpt_path), {DEMO_REFERENCE: dataset.traversal(DEMO_REFERENCE)}, "demo", str(ckpt_path)
    )
    query = dataset.query(DEMO_QUERY, [DEMO_REFERENCE])
    result = verify_checkpoint(network, query, options, Runtime(device, progress, out / "deploy"))
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
        "demo_profile": {"preset": DEMO_PRESET, **profile},
        "truth": query.truth.label,
    }
    quick = ["--quick"] if args.quick else []
    command = ["vprsnn-export", "demo", "--out", str(out), "--seed", str(args.seed), *quick]
    report = build_report([result], settings, command=command, seconds=time.perf_counter() - started)
    written = write_report(report, out / "report")
    say(f"4/4 report written ({written['json']})")
    exact = all(r.cross_implementation.passed for r in result.bits)
    print("\n".join(conclusion(report)))
    print("\nwhat the verdicts mean (docs/verify.md):")
    print("\n".join(f"  {verdict:<9}  {meaning}" for verdict, meaning in MEANINGS))
    print(f"\nfloat network, {dataset.n_places} places ({profile_text(cfg, dataset.n_places, profile)}):")
    print(format_table([row.to_dict() for row in result.float.metrics], RESULT_COLUMNS))
    print(f"scored against the {settings['truth']} (the synthetic route's places are index-aligned)")
    print("\nquantised and deployed vs float, on the same input spikes:")
    rows = [  # the verdict table's cells (bits, paired checks, same winner), the verdict without the degenerate note
        {
            **verdict_cells("", result, r),
            "verdict": r.verdict,
            "exports": cross_counts([r.cross_implementation])
            + ("" if r.cross_implementation.passed else f", {r.cross_implementation.n_failed} DIFFER"),
        }
        for r in result.bits
    ]
    print(format_table(rows, SUMMARY_COLUMNS))
    print(
        f"\nwhat it did: trained on {dataset.n_places} synthetic places ({trained:.0f} s), quantised to "
        f"{', '.join(map(str, DEMO_BITS))} bits, exported NIR, Loihi-style and ONNX and ran every file back "
        f"(cross-implementation: {'all exact' if exact else 'DIFFERENCES FOUND'}), verified against float; "
        f"{time.perf_counter() - started:.0f} s in all"
    )
    print(f"files: {out / 'float.npz'} (float network), {out / 'deploy'}/ (one folder per width), {out / 'report'}/")
    print("rerun a step:\n" + "\n".join(f"  $ {hint}" for hint in hints(out, data)))
    print("next, on your own route (docs/data.md):\n" + "\n".join(f"  > {line}" for line in OWN_DATA))
    print(f"report: {written['html'].resolve()}")
    code = 0 if exact else EXIT_CHECK_FAILED
    why = "the demo ran as intended; a width that fails is a finding" if exact else "an exported file differs"
    print(f"Verdict: {report.verdict.upper()} (the report's, the worst width's); exit code {code}: {why}")
    return code
