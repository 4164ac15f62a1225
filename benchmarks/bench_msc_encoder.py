"""How long the MSC encoder takes to encode a context (the paper: 0.003 s for 1000 points).

    python benchmarks/bench_msc_encoder.py [--latent 1024] [--width 512] [--layers 3]

Times the posterior of equation 2 (two per-point MLPs and the precision-weighted sums) at the
paper's latent size for 50 to 1000 context points, and, in the same run, one forward pass of the
8 x 512 IGR decoder on the same number of points as a yardstick. Medians over repeats, CPU or
CUDA (whichever torch sees).
"""

from __future__ import annotations

import argparse
import time

import torch

from shapebench.implicit.networks import IGRDecoder, MSCEncoder


def median_seconds(fn, repeat: int) -> float:
    fn()
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        fn()
        if torch.cuda.is_available():
            torch.cuda.synchronize()
        times.append(time.perf_counter() - start)
    return sorted(times)[len(times) // 2]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--latent", type=int, default=1024)
    parser.add_argument("--width", type=int, default=512)
    parser.add_argument("--layers", type=int, default=3)
    parser.add_argument("--repeat", type=int, default=20)
    args = parser.parse_args()
    device = torch.device("cuda" if torch.cuda.is_available() else "cpu")
    encoder = MSCEncoder(args.latent, args.width, args.layers).to(device).eval()
    decoder = IGRDecoder(args.latent).to(device).eval()
    print(
        f"device: {device}, threads: {torch.get_num_threads()}, latent {args.latent}, "
        f"encoder {args.layers} x {args.width}"
    )
    print(f"{'points':>7} {'encode ms':>10} {'decode ms (same points)':>24}")
    with torch.no_grad():
        for n in (50, 100, 300, 1000):
            pts = torch.randn(1, n, 3, device=device)
            enc = median_seconds(lambda p=pts: encoder(p), args.repeat)
            mean, _ = encoder(pts)
            dec = median_seconds(lambda p=pts, z=mean: decoder(z, p), args.repeat)
            print(f"{n:>7} {enc * 1e3:>10.2f} {dec * 1e3:>24.2f}")


if __name__ == "__main__":
    main()
