"""The benchmark table: `python bench/run.py [--quick]` (same as `vprsnn-export experiment timing`, printed).

Float path, integer simulator and onnxruntime queries/s at T=150 and 300, batch 1
and batch 100, training time per epoch, aggregation overhead, FLOPs and peak
memory, all measured side by side in one run on this machine.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the repository root: its lab, experiments/
from experiments import timing  # noqa: E402
from experiments.common import Settings  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="synthetic data, tiny sizes")
    parser.add_argument("--device", default="cpu")
    args = parser.parse_args()
    settings = (Settings.quick_settings if args.quick else Settings)(device=args.device, progress=False, seeds=(1,))
    print(timing.render(timing.run(settings), out_dir=None))


if __name__ == "__main__":
    main()
