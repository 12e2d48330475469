"""Refit a decoder's held-out codes under another latent-optimisation setting, beside its own.

    PYTHONPATH=. python notebooks/refit_codes.py DECODER_DIR OUT_DIR [--splits test] [--iterations 800]
        [--samples 500] [--lr 1e-2] [--world W]
    PYTHONPATH=. python notebooks/r2n2_ceiling.py DECODER_DIR --codes OUT_DIR --split test --level 0.4

Writes OUT_DIR/codes_<split>.pt for each split (`optimise_codes` on the frozen decoder, the learning rate
dropped tenfold at 3/4 of the iterations) and OUT_DIR/refit.json (the setting, seconds, threads). The
decoder folder is not touched: its own codes stay what its encoder, temperature and fusion were fitted on.
A ceiling measured with refitted codes says what the decoder can draw, not what a shipped model's
calibrations were fitted against.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from r2n2_ceiling import trained_world  # noqa: E402

from ushape import atomic  # noqa: E402
from ushape.decoder.artifacts import codes_file, load_decoder, save_codes  # noqa: E402
from ushape.decoder.fit import reconstruct_split  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("decoder_dir", type=Path)
    parser.add_argument("out_dir", type=Path)
    parser.add_argument("--splits", default="test", help="comma-separated: val,test")
    parser.add_argument("--iterations", type=int, default=800)
    parser.add_argument("--samples", type=int, default=500, help="SDF samples a step and shape")
    parser.add_argument("--lr", type=float, default=1e-2)
    parser.add_argument("--world", default=None, help="the r2n2 world (default: the one DONE names)")
    args = parser.parse_args()
    world = trained_world(parser, args.decoder_dir, args.world)
    decoder = load_decoder(args.decoder_dir).eval()
    setting = {
        "iterations": args.iterations,
        "lr": args.lr,
        "lr_drop_at": int(args.iterations * 0.75),
        "samples_per_iter": args.samples,
    }
    args.out_dir.mkdir(parents=True, exist_ok=True)
    record = {"decoder": str(args.decoder_dir), "world": str(world), "setting": setting, "seconds": {}}
    for split in args.splits.split(","):
        started = time.perf_counter()
        save_codes(args.out_dir / codes_file(split), reconstruct_split(decoder, world, split, setting))
        record["seconds"][split] = round(time.perf_counter() - started, 1)
        print(f"{split}: {record['seconds'][split]} s")
    record["threads"] = torch.get_num_threads()
    atomic.write_text(args.out_dir / "refit.json", json.dumps(record, indent=1))


if __name__ == "__main__":
    main()
