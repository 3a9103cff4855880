"""The options and the run of `vprsnn-export experiment NAME` (regenerate one of the paper's tables or figures as
JSON + Markdown + plots): the library's thin `experiment` command loads this module from the repository.

Its top imports no torch (the command's ``--help``); the experiments load when one runs."""

from __future__ import annotations

import argparse
import importlib
import json
import pkgutil
import re
import shlex
from dataclasses import replace
from pathlib import Path
from typing import Any

import experiments
from experiments.settings import DATA_ENV, DOCS_RESULTS, NORDLAND, Settings, Variant, data_settings, results_dir
from vprsnn_export.cluster import CLUSTER_HELP, parse_cluster
from vprsnn_export.commands._common import integer, parse_int_list, parse_names, parse_value
from vprsnn_export.errors import InvalidValueError
from vprsnn_export.io.fileio import atomic_write_text

#: The modules of experiments/ that are not experiments.
HELPER_MODULES = {"command", "common", "plots", "query", "settings", "sourcehash"}


def experiment_modules() -> dict:
    names = sorted(m.name for m in pkgutil.iter_modules(experiments.__path__) if m.name not in HELPER_MODULES)
    return {name: importlib.import_module(f"{experiments.__name__}.{name}") for name in names}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The options of ``vprsnn-export experiment`` on the command's parser; its handler is :func:`run`."""
    parser.add_argument("name", help="experiment name, or 'list'")
    parser.add_argument("--quick", action="store_true", help="tiny synthetic size (CI); otherwise the real data")
    output = parser.add_mutually_exclusive_group()
    output.add_argument(
        "--out",
        default=str(results_dir()),
        help="output folder (default: %(default)s, that is $VPRSNN_RESULTS, else ~/.cache/vprsnn-export/results: "
        "outside the repository)",
    )
    output.add_argument(
        "--update-docs",
        action=UpdateDocs,
        nargs=0,
        default=False,
        help=f"write the committed pages instead: {DOCS_RESULTS}/NAME.{{json,md,png}} of the repository "
        "this runs in (run it from the repository root; not with --quick)",
    )
    parser.add_argument(
        "--data",
        metavar="DIR",
        help=f"the data folder (places.csv and, for the paper's tables, subset_100_places.csv) or a place manifest "
        f"(default: ${DATA_ENV}, else {NORDLAND} relative to the working folder, i.e. run from the repository root; "
        "with --quick the synthetic route)",
    )
    parser.add_argument(
        "--seeds",
        type=integer,
        help="number of independently trained networks (seeds 1..N; default: "
        f"{len(Settings().seeds)}; with --quick {len(Settings.quick_settings().seeds)})",
    )
    parser.add_argument("--reference", help="the reference traversal (default: summer)")
    parser.add_argument("--query", help="the query traversal (default: winter)")
    parser.add_argument("--device", default="cpu", help="auto, cpu or cuda")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="config override")
    parser.add_argument(
        "--grid",
        action="append",
        default=[],
        metavar="NAME=PRESET[,KEY=VALUE...]",
        help="experiment sweep: one variant of the grid (repeatable; default: the grid the sweep page lists)",
    )
    parser.add_argument(
        "--module-sizes",
        metavar="P[,P...]",
        help="experiment route: the module sizes to measure, the first one with every seed (default 100,50,200)",
    )
    parser.add_argument(
        "--checkpoint",
        action="append",
        default=[],
        metavar="FILE",
        help="experiment cost: measure this trained checkpoint on its own places (repeatable) instead of training",
    )
    parser.add_argument(
        "--threads", type=integer, default=None, metavar="N", help="CPU threads (default: OMP_NUM_THREADS, else 1)"
    )
    parser.add_argument(
        "--cluster",
        help=f"train each network's modules on a Ray cluster, one task per module ({CLUSTER_HELP}); the same "
        "networks bit for bit (experiment sweep, route and the others)",
    )
    parser.add_argument("--quiet", action="store_true")
    parser.set_defaults(handler=run)


class UpdateDocs(argparse.Action):
    """``--update-docs``: the output is the repository's docs/results (it must exist under the working folder)."""

    def __call__(
        self,
        parser: argparse.ArgumentParser,
        namespace: argparse.Namespace,
        values: Any,
        option_string: str | None = None,
    ) -> None:
        if not Path(DOCS_RESULTS).is_dir():
            parser.error(
                f"--update-docs writes {DOCS_RESULTS}/ of the repository: run it from the repository root "
                f"({Path(DOCS_RESULTS).absolute()} is not a folder)"
            )
        namespace.update_docs = True
        namespace.out = DOCS_RESULTS


def settings_from_args(args: argparse.Namespace) -> Settings:
    changes: dict[str, Any] = {"device": args.device, "progress": not args.quiet}
    if args.cluster is not None:
        changes["cluster"] = parse_cluster(args.cluster, threads=args.threads)
    if args.seeds is not None:
        if not 1 <= args.seeds <= 1000:
            raise InvalidValueError(f"--seeds expects an integer from 1 to 1000, got {args.seeds}")
        changes["seeds"] = tuple(range(1, args.seeds + 1))
    settings = Settings.quick_settings(**changes) if args.quick else Settings(**changes)
    overrides = dict(settings.overrides)
    for item in args.set:
        key, sep, raw = item.partition("=")
        if not sep:
            raise InvalidValueError(f"--set expects KEY=VALUE, got {item!r}")
        overrides[key.strip()] = parse_value(raw.strip())
    extra: dict[str, Any] = {"overrides": overrides, "grid": tuple(parse_grid_entry(item) for item in args.grid)}
    if args.data is not None or not args.quick:
        extra.update(data_settings(args.data))
    for name in ("reference", "query"):
        if getattr(args, name) is not None:
            extra[name] = parse_names(getattr(args, name), f"--{name}")[0]
    if args.module_sizes is not None:
        if args.name != "route":
            raise InvalidValueError(f"--module-sizes applies only to experiment route, not {args.name!r}")
        extra["module_sizes"] = parse_int_list(args.module_sizes, "--module-sizes")
        if len(set(extra["module_sizes"])) != len(extra["module_sizes"]):
            raise InvalidValueError(f"--module-sizes names a size twice: {args.module_sizes!r}")
    if args.checkpoint:
        if args.name != "cost":
            raise InvalidValueError(f"--checkpoint applies only to experiment cost, not {args.name!r}")
        extra["checkpoints"] = tuple(args.checkpoint)
    return replace(settings, **extra)


def parse_grid_entry(item: str) -> Variant:
    """``"dog+g=dog,assignment.gamma=0.1"`` -> Variant("dog+g", "dog", {"assignment.gamma": 0.1})."""
    name, sep, rest = item.partition("=")
    parts = re.split(r",(?=\s*[\w.]+\s*=)", rest)  # commas inside values (lists) stay
    if not sep or not name.strip() or not parts[0].strip() or "=" in parts[0]:
        raise InvalidValueError(f"--grid expects NAME=PRESET[,KEY=VALUE...], got {item!r}")
    overrides = {}
    for part in parts[1:]:
        key, _, raw = part.partition("=")
        overrides[key.strip()] = parse_value(raw.strip())
    return Variant(name.strip(), parts[0].strip(), overrides)


def run(args: argparse.Namespace) -> int:
    from experiments.common import document

    modules = experiment_modules()
    if args.name == "list":
        for name, module in modules.items():
            print(f"{name:14s} {module.DESCRIPTION}")
        return 0
    if args.name not in modules:
        raise InvalidValueError(f"unknown experiment {args.name!r}; choose from {', '.join(modules)}")
    module = modules[args.name]
    if getattr(args, "update_docs", False) and args.quick:
        raise InvalidValueError(f"--update-docs writes the committed pages of {DOCS_RESULTS}: not with --quick")
    if args.grid and args.name != "sweep":
        raise InvalidValueError(f"--grid applies only to experiment sweep, not {args.name!r}")
    settings = settings_from_args(args)
    results = module.run(settings)
    command = "vprsnn-export " + " ".join(shlex.quote(a) for a in args.argv)
    results["command"] = command
    results["output"] = args.out
    out = Path(args.out)
    name = module.stem(settings) if hasattr(module, "stem") else args.name  # a page per data set, where it says so
    stem = f"{name}_quick" if args.quick else name
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_text(out / f"{stem}.json", json.dumps(results, indent=1, default=float))
    body = module.render(results, out, stem)
    atomic_write_text(out / f"{stem}.md", document(args.name, module.DESCRIPTION, stem, results, body))
    print(f"wrote {out / (stem + '.json')} and {out / (stem + '.md')}")
    return 0
