"""Training throughput of KPlanesField: compiled fused kernel vs pure-PyTorch gather vs grid_sample reference.

Run: ``python benchmarks/bench_fields.py [--rays R] [--samples-per-ray S] [--iters K] [--threads T]
[--config fit|default|paper] [--uniform]``

Backends: ``auto`` (the compiled fused kernel), ``gather`` (pure PyTorch embedding_bag / index_add_),
``grid_sample`` (the field's reference path: same optimised MLPs, grid_sample interpolation) and ``plain``
(:class:`PlainKPlanes` below: K-Planes written the straightforward way).

One training step = forward (density + colour) on R*S points, MSE colour loss + density term, backward,
``Adam(fused=True).step()`` (measured 3 ms vs 23 ms for the default foreach Adam on the 4M-parameter
table, 1 thread), ``zero_grad(set_to_none=True)``.  Points are R random rays through the AABB with S
stratified samples each (what the trainer feeds; ``--uniform`` draws i.i.d. points instead).  The backends are run
round-robin (one step each, K rounds, after one warm-up round) so that load from other processes on a shared
machine hits all of them alike; the median wall time and the median process CPU time per step are reported.
The fp32 matmul rate (2048^3) is measured before and after each config; "% of peak" uses their median
(same thread count) and an analytic
count of the field's FLOPs per sample (MLP matmuls x 3 for forward + backward, plus the interpolation).
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

import torch

from senerf.fields import KPlanesField
from senerf.fields.ckernel import kernel_status
from senerf.fields.interp import PAIRS

CONFIGS = {
    # what `senerf-fit` builds for lego at 100x100 (choose_model: base 56, scales (1, 2), 16 features;
    # checked by tests/fields/test_bench_configs.py), i.e. the field every lego benchmark trains
    "fit": dict(resolution=56, n_features=16, multires=(1, 2)),
    # KPlanesField's constructor defaults (three scales)
    "default": dict(resolution=64, n_features=16, multires=(1, 2, 4)),
    "paper": dict(resolution=128, n_features=32, multires=(1, 2, 4)),
}
BACKENDS = ("auto", "gather", "grid_sample", "plain")


class PlainKPlanes(torch.nn.Module):
    """The straightforward reference: K-Planes as usually written in pure PyTorch (one ``(1, F, r, r)``
    parameter per plane, ``grid_sample(align_corners=True)`` per plane, Hadamard product, ``nn.Sequential``
    MLPs, no chunking, the SH encoding as a PyTorch expression: ``sh_encoding_reference``).
    Same architecture, sizes and initial values as :class:`KPlanesField` built with the same arguments."""

    def __init__(self, field: KPlanesField):
        super().__init__()
        self.aabb = field.aabb.clone()
        self.planes = torch.nn.ParameterList(
            [torch.nn.Parameter(field.plane(s, p).detach().permute(2, 0, 1).unsqueeze(0).clone())
             for s in range(len(field.resolutions)) for p in range(3)])
        import copy
        self.density_net = copy.deepcopy(field.density_net)
        self.color_net = copy.deepcopy(field.color_net)
        for m in list(self.density_net) + list(self.color_net):
            if isinstance(m, torch.nn.ReLU):
                m.inplace = False
        self.n_scales = len(field.resolutions)

    def forward(self, xyz, dirs):
        from senerf.fields.base import trunc_exp
        from senerf.fields.encoding import sh_encoding_reference as sh_encoding
        u = (xyz - self.aabb[0]) * (2.0 / (self.aabb[1] - self.aabb[0])) - 1.0
        inside = (u.abs() <= 1).all(-1).float()
        feats = []
        for s in range(self.n_scales):
            f = 1.0
            for p, (a, b) in enumerate(PAIRS):
                grid = u[:, [a, b]].clamp(-1, 1).view(1, -1, 1, 2)
                v = torch.nn.functional.grid_sample(self.planes[3 * s + p], grid, align_corners=True)
                f = f * v.view(v.shape[1], -1).t()
            feats.append(f)
        h = self.density_net(torch.cat(feats, -1))
        sigma = trunc_exp(h[:, 0]) * inside
        rgb = torch.sigmoid(self.color_net(torch.cat([h[:, 1:], sh_encoding(dirs)], -1)))
        return sigma, rgb


def matmul_flops(n: int = 2048, reps: int = 5) -> float:
    a, b = torch.randn(n, n), torch.randn(n, n)
    torch.mm(a, b)
    times = []
    for _ in range(reps):
        t0 = time.perf_counter()
        torch.mm(a, b)
        times.append(time.perf_counter() - t0)
    return 2.0 * n ** 3 / statistics.median(times)


def field_flops_per_sample(field: KPlanesField) -> float:
    """Forward + backward FLOPs per sample: 3 x forward (backward of a matmul costs two matmuls)."""
    macs = sum(m.in_features * m.out_features for net in (field.density_net, field.color_net)
               for m in net if isinstance(m, torch.nn.Linear))
    s, f, p = len(field.resolutions), field.n_features, len(PAIRS)
    fwd = 2 * macs + s * p * 4 * 2 * f + s * 2 * f      # matmuls, 4-corner blends, Hadamard
    return 3.0 * fwd


def ray_points(aabb, n_rays, n_per_ray, gen):
    lo, hi = aabb
    centre, half = (lo + hi) / 2, (hi - lo) / 2
    o = torch.randn(n_rays, 3, generator=gen)
    o = centre + 3.0 * half.norm() * o / o.norm(dim=-1, keepdim=True)
    target = centre + (torch.rand(n_rays, 3, generator=gen) * 2 - 1) * half * 0.8
    d = torch.nn.functional.normalize(target - o, dim=-1)
    dist = (target - o).norm(dim=-1, keepdim=True)
    near, far = dist - half.norm(), dist + half.norm()
    t = near + (torch.arange(n_per_ray) + torch.rand(n_rays, n_per_ray, generator=gen)) / n_per_ray * (far - near)
    xyz = (o[:, None] + t[..., None] * d[:, None]).reshape(-1, 3)
    return xyz, d[:, None].expand(n_rays, n_per_ray, 3).reshape(-1, 3)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rays", type=int, default=2048)
    ap.add_argument("--samples-per-ray", type=int, default=48)
    ap.add_argument("--iters", type=int, default=7)
    ap.add_argument("--threads", type=int, default=0, help="torch.set_num_threads (0: leave as is)")
    ap.add_argument("--config", choices=sorted(CONFIGS), action="append")
    ap.add_argument("--uniform", action="store_true", help="i.i.d. uniform points instead of ray samples")
    args = ap.parse_args(argv)
    if args.threads:
        torch.set_num_threads(args.threads)
    n = args.rays * args.samples_per_ray
    print(f"torch {torch.__version__}, threads {torch.get_num_threads()}, cpus {os.cpu_count()}, "
          f"load avg {os.getloadavg()[0]:.2f}; {n} samples/step "
          f"({'uniform points' if args.uniform else f'{args.rays} rays x {args.samples_per_ray}'}); "
          f"median of {args.iters} round-robin steps")
    flops = [matmul_flops()]
    aabb = torch.tensor([[-1.3] * 3, [1.3] * 3])
    for name in args.config or ["fit", "default"]:
        cfg = CONFIGS[name]
        gen = torch.Generator().manual_seed(0)
        if args.uniform:
            xyz = aabb[0] + torch.rand(n, 3, generator=gen) * (aabb[1] - aabb[0])
            dirs = torch.nn.functional.normalize(torch.randn(n, 3, generator=gen), dim=-1)
        else:
            xyz, dirs = ray_points(aabb, args.rays, args.samples_per_ray, gen)
        target = torch.rand(n, 3, generator=gen)
        fields = {b: KPlanesField(aabb, generator=torch.Generator().manual_seed(0), backend=b, **cfg)
                  for b in BACKENDS[:3]}
        fields["plain"] = PlainKPlanes(fields["grid_sample"])
        opts = {b: torch.optim.Adam(f.parameters(), lr=0.01, fused=True) for b, f in fields.items()}
        wall = {b: [] for b in BACKENDS}
        cpu = {b: [] for b in BACKENDS}
        for it in range(args.iters + 1):
            for b in BACKENDS:
                w0, c0 = time.perf_counter(), time.process_time()
                sigma, rgb = fields[b](xyz, dirs)
                loss = (rgb - target).square().mean() + 1e-3 * sigma.mean()
                opts[b].zero_grad(set_to_none=True)
                loss.backward()
                opts[b].step()
                if it:
                    wall[b].append(time.perf_counter() - w0)
                    cpu[b].append(time.process_time() - c0)
        flops.append(matmul_flops())
        peak = statistics.median(flops)
        fps = field_flops_per_sample(fields["auto"])
        print(f"[{name}] {cfg}; fused kernel: {kernel_status()}; fp32 matmul 2048^3 "
              f"{' / '.join(f'{x / 1e9:.0f}' for x in flops)} GFLOP/s; field ~{fps / 1e3:.1f} kFLOP/sample "
              f"(fwd+bwd)")
        rate = {}
        for b in BACKENDS:
            tw, tc = statistics.median(wall[b]), statistics.median(cpu[b])
            rate[b] = n / tw
            print(f"  {b:12s} step wall {tw * 1e3:7.1f} ms (spread {min(wall[b]) * 1e3:.0f}-{max(wall[b]) * 1e3:.0f}), "
                  f"cpu {tc * 1e3:7.1f} ms | {rate[b] / 1e6:.3f} M samples/s wall, "
                  f"{n / tc / 1e6:.3f} M samples/cpu-s | {rate[b] * fps / peak * 100:.1f}% of matmul peak")
        print(f"  ratios (wall): auto/plain {rate['auto'] / rate['plain']:.2f}x, "
              f"auto/grid_sample {rate['auto'] / rate['grid_sample']:.2f}x, "
              f"gather/grid_sample {rate['gather'] / rate['grid_sample']:.2f}x; 1 M samples/s target "
              f"{'met' if rate['auto'] >= 1e6 else 'NOT met'} (wall, {torch.get_num_threads()} threads)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
