"""Where do the learned implicit rows lose thin parts: the data, the training samples, or the field?

    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/thin_parts.py geometry
        [--categories airplane,lamp,table,chair] [--objects 2] [--profile standard]
    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/thin_parts.py field -m msc --checkpoint PATH
        --seed S [--context 1000] [--categories ...] [--objects 2] [--pictures DIR]
        [-O key=value ...]

Validation objects only (``<category>/val-NNN``, ``-D test_per_category=2`` as the committed
validation cells): never test objects. Everything is in the benchmark's unit-radius frame.

``geometry`` (no model) prints per object: the local **thickness** of the surface (the distance
from a surface point along its inward normal to the opposite side: a wing's thickness, a pole's
diameter; 20,000 area-weighted samples), the area share thinner than ``--thin`` (0.05), their
median and 5th percentile against the marching-cubes voxel (2 x 1.05 / 64 and / 256); whether
the ground-truth sign is right inside thin parts (``mesh.contains``, which the SDF and occupancy
samples use, against the exact generalised winding number at the mid-points of thin parts); the
visible training points whose oriented normal points into the solid; and how the training
samplers cover thin parts: share of the visible (training) surface points, share of DeepSDF's SDF
samples (OccNet's paper queries) and of uniform queries in [-1.1, 1.1]^3 (ConvONet) that lie
inside a thin part, against the samplers' noise (sigma 0.071 and 0.022).

``field`` completes each object from the run's own context of ``--context`` points with a trained
checkpoint and reads the field at ground-truth points of the thin parts: at the surface itself,
at the part's mid-plane (p - t/2 n: inside for a correct field) and at p + d n for d = 0.02, 0.05
(outside for a correct field; inside means the completion wraps the part in a blob). The same is
printed for the thick rest of the surface, with chamfer-l2 x1000 of the completion, the share of
thin ground-truth points farther than 0.03 from the completion (the part is missing) and the
95th percentile of completion-to-truth distances (extra surface). ``--pictures DIR`` writes one
slice of the field through a thin part per object (grey: the object's inside; black line: the
field's level set; dots: context points within 0.02 of the slice).
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
from pathlib import Path

import numpy as np
import trimesh

sys.path.insert(0, str(Path(__file__).parent))

#: Surface samples per object for thickness and the field probes.
SAMPLES = 20_000
#: The meshing box half-side (shapebench.geometry.meshing.extract_mesh's default bound).
BOUND = 1.05
#: DeepSDF's perturbation variances (shapebench.preprocess.samples.NEAR_VARIANCES).
NEAR_SIGMAS = (math.sqrt(0.005), math.sqrt(0.0005))


def winding_number(mesh: trimesh.Trimesh, points: np.ndarray, chunk: int = 64) -> np.ndarray:
    """Generalised winding number of ``points`` (1 inside a closed outward mesh, 0 outside):
    the exact solid-angle sum (Van Oosterom and Strackee), independent of any ray test."""
    tri = np.asarray(mesh.triangles, dtype=np.float64)
    out = np.empty(len(points))
    for i in range(0, len(points), chunk):
        p = points[i : i + chunk, None, None, :]
        a, b, c = (tri[None, :, k, :] - p[:, :, 0, :] for k in range(3))
        la, lb, lc = (np.linalg.norm(v, axis=-1) for v in (a, b, c))
        num = np.einsum("ijk,ijk->ij", a, np.cross(b, c))
        den = (
            la * lb * lc
            + np.einsum("ijk,ijk->ij", a, b) * lc
            + np.einsum("ijk,ijk->ij", b, c) * la
            + np.einsum("ijk,ijk->ij", c, a) * lb
        )
        out[i : i + chunk] = 2.0 * np.arctan2(num, den).sum(axis=1) / (4.0 * math.pi)
    return out


def thickness(mesh: trimesh.Trimesh, points: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """Distance from each surface point along ``-normal`` to the mesh (inf where no hit)."""
    eps = 1e-4
    origins = points - eps * normals
    loc, ray, _ = mesh.ray.intersects_location(origins, -normals, multiple_hits=False)
    out = np.full(len(points), np.inf)
    out[ray] = np.linalg.norm(loc - origins[ray], axis=1) + eps
    return out


def unit_mesh(dataset, ref) -> trimesh.Trimesh:
    from shapebench.preprocess.normalize import normalize

    return normalize(dataset.mesh(ref))[0]


def surface_samples(mesh: trimesh.Trimesh, ref_id: str) -> tuple[np.ndarray, ...]:
    """(points, outward face normals, thickness) of SAMPLES area-weighted surface points, the
    same for every call on one object."""
    from shapebench.geometry.sampling import sample_surface
    from shapebench.hashing import stable_seed

    rng = np.random.default_rng(stable_seed("thin-parts", ref_id) % (2**32))
    pts, face = sample_surface(mesh.vertices, mesh.faces, SAMPLES, rng)
    nrm = np.asarray(mesh.face_normals, dtype=np.float64)[face]
    return pts, nrm, thickness(mesh, pts, nrm)


def resolve(args):
    from ladder import resolve as ladder_resolve

    return ladder_resolve(args)


def pick_refs(dataset, categories: list[str], per_category: int):
    refs = [r for r in dataset.objects("validation") if r.category in categories]
    out = []
    for cat in categories:
        out += [r for r in refs if r.category == cat][:per_category]
    return out


def geometry(args) -> None:
    from shapebench.geometry.nearest import kdtree
    from shapebench.preprocess.samples import sdf_samples

    args.method = "msc"  # any trainable method: only the dataset is used
    _, dataset = resolve(args)
    voxels = (2 * BOUND / 64, 2 * BOUND / 256)
    print(f"voxel: {voxels[0]:.4f} (64), {voxels[1]:.4f} (256); thin: thickness < {args.thin}")
    print(
        f"{'object':<18} {'thin area':>9} {'t50 thin':>8} {'t05':>6} {'t05/vox64':>9} "
        f"{'sign err':>9} {'flipped n':>9} {'vis thin':>8} {'sdf in-thin':>11} "
        f"{'sdf in':>7} {'kept':>5} {'unif in-thin':>12} {'closed':>6}"
    )
    for ref in pick_refs(dataset, args.categories.split(","), args.objects):
        mesh = unit_mesh(dataset, ref)
        data = dataset.load(ref)
        pts, nrm, t = surface_samples(mesh, ref.id)
        thin = t < args.thin
        tt = t[thin] if thin.any() else np.array([np.nan])
        # (b) the ground-truth sign at the mid-plane of thin parts: ray test vs winding number.
        rng = np.random.default_rng(0)
        idx = np.flatnonzero(thin & np.isfinite(t))
        idx = rng.choice(idx, size=min(400, len(idx)), replace=False) if len(idx) else idx
        mid = pts[idx] - 0.5 * t[idx, None] * nrm[idx]
        truth = winding_number(mesh, mid) > 0.5
        ray = mesh.contains(mid)
        sign_err = f"{int((truth != ray).sum())}/{len(mid)}" if len(mid) else "-"
        # The visible (training and context) points: flipped normals and the thin share.
        vis, vn = data.surface_points.astype(np.float64), data.surface_normals.astype(np.float64)
        sub = rng.choice(len(vis), size=min(3000, len(vis)), replace=False)
        _, _, tri = trimesh.proximity.closest_point(mesh, vis[sub])
        flipped = np.einsum("ij,ij->i", mesh.face_normals[tri], vn[sub]) < 0
        tree = kdtree(pts)
        _, nn = tree.query(vis, k=1)
        vis_thin = float(thin[nn].mean())
        # OccNet's paper queries / DeepSDF's samples: inside labels that fall in thin parts.
        sdf = sdf_samples(mesh, 20_000, np.random.default_rng(1))
        _, nn = tree.query(sdf[:, :3], k=1)
        inside = sdf[:, 3] < 0
        in_thin = inside & thin[nn]
        # ConvONet's uniform queries (and OccNet's official ones).
        uni = np.random.default_rng(2).uniform(-1.1, 1.1, size=(100_000, 3))
        _, nn = tree.query(uni, k=1)
        uni_thin = mesh.contains(uni) & thin[nn]
        print(
            f"{ref.id:<18} {thin.mean():>9.3f} {np.median(tt):>8.4f} "
            f"{np.percentile(t[np.isfinite(t)], 5):>6.4f} "
            f"{np.percentile(t[np.isfinite(t)], 5) / voxels[0]:>9.2f} {sign_err:>9} "
            f"{flipped.mean():>9.4f} {vis_thin:>8.3f} {in_thin.mean():>11.4f} "
            f"{inside.mean():>7.3f} {len(sdf) / 20_000:>5.2f} {uni_thin.mean():>12.5f} "
            f"{mesh.is_watertight and mesh.is_winding_consistent!s:>6}"
        )
    print(
        "columns: thin area = share of the surface thinner than --thin; t50 thin = median "
        "thickness there; t05 = 5th percentile over the whole surface; sign err = mid-points of "
        "thin parts where mesh.contains disagrees with the winding number; flipped n = visible "
        "points whose normal points inward; vis thin = share of visible points on thin parts; "
        "sdf in-thin = share of 20k SDF samples labelled inside a thin part (sdf in: inside "
        "at all; kept: share not dropped as ambiguous); unif in-thin = share of uniform "
        "queries inside a thin part; closed = watertight and consistently wound. "
        f"Sampler noise sigmas: {NEAR_SIGMAS[0]:.4f}, {NEAR_SIGMAS[1]:.4f}."
    )


def probe(values: np.ndarray, inside_negative: bool, level: float) -> np.ndarray:
    """Whether the field calls each value inside."""
    return values < level if inside_negative else values > level


def slice_picture(path: Path, field, level, inside_neg, mesh, p0, n0, ctx_pts, surf, title) -> None:
    """Two slices through ``p0``: across the thin part (its normal and the longest other axis)
    and along it (the plane of the object's two longest axes nearest to the part's tangent)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    extent = np.ptp(mesh.vertices, axis=0)
    axes = np.eye(3)
    u = n0 / np.linalg.norm(n0)
    other = max((a for a in range(3) if abs(u @ axes[a]) < 0.7), key=lambda a: extent[a], default=0)
    v = axes[other] - (axes[other] @ u) * u
    v /= np.linalg.norm(v)
    normal_axis = int(np.argmax(np.abs(u)))  # the world axis closest to the part's normal
    a, b = (axes[i] for i in range(3) if i != normal_axis)
    fig, panels = plt.subplots(1, 2, figsize=(10, 5))
    for ax, (pu, pv), label in zip(
        panels,
        ((u, v), (a, b)),
        ("across: along the part's normal", "along the part (plane of its tangent)"),
        strict=True,
    ):
        _slice(ax, field, level, inside_neg, mesh, p0, pu, pv, ctx_pts, surf)
        ax.set_xlabel(label + " (red: field inside; blue: object)", fontsize=8)
    fig.suptitle(title, fontsize=9)
    fig.savefig(path, dpi=100, bbox_inches="tight")
    plt.close(fig)


def _slice(ax, field, level, inside_neg, mesh, p0, u, v, ctx_pts, surf) -> None:
    w = np.cross(u, v)
    s = np.linspace(-BOUND, BOUND, 241)
    gu, gv = np.meshgrid(s, s, indexing="ij")
    base = p0 - (p0 @ u) * u - (p0 @ v) * v  # the plane through p0 spanned by u, v
    grid = base + gu[..., None] * u + gv[..., None] * v
    flat = grid.reshape(-1, 3)
    values = field(flat).reshape(gu.shape)
    truth = mesh.contains(flat).reshape(gu.shape)
    near = ctx_pts[np.abs((ctx_pts - p0) @ w) < 0.02]
    inside = values < level if inside_neg else values > level
    ext = (-BOUND, BOUND, -BOUND, BOUND)
    ax.imshow(inside.T, origin="lower", extent=ext, cmap="Reds", alpha=0.35, vmin=0, vmax=1.5)
    ax.contour(gu, gv, values, levels=[level], colors="k", linewidths=1.0)
    ax.contourf(gu, gv, truth.astype(float), levels=[0.5, 1.5], colors=["tab:blue"])
    ax.contour(gu, gv, truth.astype(float), levels=[0.5], colors=["tab:blue"], linewidths=0.8)
    gt = surf[np.abs((surf - p0) @ w) < 0.03]  # the object's surface near the slice
    ax.scatter(gt @ u, gt @ v, s=0.3, c="tab:blue")
    ax.scatter(near @ u, near @ v, s=3, c="tab:red")
    ax.scatter([p0 @ u], [p0 @ v], s=30, marker="x", c="tab:green")


def _median(x: np.ndarray, mask: np.ndarray) -> float:
    return float(np.median(x[mask])) if mask.any() else math.nan


def _share(x: np.ndarray, mask: np.ndarray) -> float:
    return float(x[mask].mean()) if mask.any() else math.nan


def field_probe(args) -> None:
    from ladder import chamfer_x1000

    from shapebench.api.contexts import ContextStore
    from shapebench.geometry.nearest import kdtree

    resolved, dataset = resolve(args)
    method = resolved.cls(resolved.options)
    method.load_checkpoint(args.checkpoint)
    neg, level = method.inside_is_negative, method.level()
    store = ContextStore(dataset.cache_root, dataset.data_fingerprint())
    if args.pictures:
        Path(args.pictures).mkdir(parents=True, exist_ok=True)
    print(f"{args.method} seed {args.seed}, {args.context} context points, level {level:.3f}")
    print(
        f"{'object':<18} {'cd x1e3':>8} {'thin':>5} | {'f(p) thin':>9} {'mid in':>6} "
        f"{'+.02 in':>7} {'+.05 in':>7} | {'f(p) thick':>10} {'+.05 in':>7} | "
        f"{'thin miss':>9} {'pred p95':>8} | {'pred>gt':>7} {'gt>pred':>7}"
    )
    rows = []
    for ref in pick_refs(dataset, args.categories.split(","), args.objects):
        mesh = unit_mesh(dataset, ref)
        data = dataset.load(ref)
        pts, nrm, t = surface_samples(mesh, ref.id)
        ok = np.isfinite(t)
        thin, thick = ok & (t < args.thin), ok & (t >= args.thin)
        ctx = store.context(data, args.context, args.seed)
        code = next(iter(method.encode([ctx])))
        # MSC's codes are (posterior mean or optimised code, variance): the field is the first.
        field = method.field(code[0] if isinstance(code, tuple) else code)
        f_p = field(pts)
        sgn = 1.0 if neg else -1.0  # so that "inside" is negative in the printed f(p)
        mid_in = probe(field(pts - 0.5 * t[:, None].clip(max=1) * nrm), neg, level)
        out2 = probe(field(pts + 0.02 * nrm), neg, level)
        out5 = probe(field(pts + 0.05 * nrm), neg, level)
        try:
            comp = method.decode(code, ctx, len(data.gt_points))
            cd = chamfer_x1000(comp, data, ctx)
            d_gt, _ = kdtree(comp.points).query(pts, k=1)
            d_pred, _ = kdtree(pts).query(comp.points, k=1)
            miss = float((d_gt[thin] > 0.03).mean()) if thin.any() else math.nan
            p95 = float(np.percentile(d_pred, 95))
            # The two halves of chamfer-l2 (x1000): extra surface, then missing surface.
            halves = (1000 * float(np.mean(d_pred**2)), 1000 * float(np.mean(d_gt**2)))
        except Exception:  # no surface at all
            cd, miss, p95, halves = math.nan, 1.0, math.nan, (math.nan, math.nan)

        signed = sgn * (f_p - level)
        row = (
            ref.id,
            cd,
            thin.mean(),
            _median(signed, thin),
            _share(mid_in, thin),
            _share(out2, thin),
            _share(out5, thin),
            _median(signed, thick),
            _share(out5, thick),
            miss,
            p95,
            *halves,
        )
        rows.append(row)
        print(
            f"{row[0]:<18} {row[1]:>8.2f} {row[2]:>5.2f} | {row[3]:>9.4f} {row[4]:>6.2f} "
            f"{row[5]:>7.2f} {row[6]:>7.2f} | {row[7]:>10.4f} {row[8]:>7.2f} | "
            f"{row[9]:>9.2f} {row[10]:>8.3f} | {row[11]:>7.2f} {row[12]:>7.2f}"
        )
        if args.pictures and thin.any():
            # The thin point with the largest error of the completion's field.
            k = np.flatnonzero(thin)[np.argmax(np.abs(f_p[thin] - level))]
            name = f"{args.method}-s{args.seed}-k{args.context}-{ref.id.replace('/', '_')}.png"
            slice_picture(
                Path(args.pictures) / name,
                field,
                level,
                neg,
                mesh,
                pts[k],
                nrm[k],
                ctx.points.astype(np.float64),
                pts,
                f"{args.method} seed {args.seed} {ref.id} k={args.context}: cd {cd:.1f}",
            )
    print(
        "columns: f(p) = median field at ground-truth points (sign: negative inside; logits "
        "minus the level, negated, for occupancy fields); mid in = share of thin parts' "
        "mid-points the field calls inside; +.02/+.05 in = share of points 0.02/0.05 outside "
        "the surface the field calls inside (blob); thin miss = share of thin ground-truth "
        "points farther than 0.03 from the completion; pred p95 = 95th percentile of "
        "completion-to-truth distances; pred>gt and gt>pred: the two halves of chamfer-l2 x1000 "
        "(extra surface, missing surface; against the 20,000 surface samples)."
    )


def _means(values) -> list[float]:
    return [float(v.mean()) if len(v) else math.nan for v in values]


def _loss_rows(method, ref, data, mesh, pts, nrm, code_index, args) -> tuple[float, ...]:
    """One object's training-loss terms, split between thin parts and the rest (see ``loss``)."""
    import torch

    from shapebench.api.types import Context
    from shapebench.implicit.losses import eikonal, gradient, offsurface_samples

    t = thickness(mesh, pts, nrm)
    thin = torch.from_numpy(np.isfinite(t) & (t < args.thin))
    ctx = Context(ref, pts.astype(np.float32), None, seed=args.seed)
    module = method.module
    if method.inside_is_negative:  # IGR / MSC / MSC-hier: |f| and ||grad f - n|| per point
        if code_index is not None:  # an auto-decoder's trained code
            z = module.latents[code_index][None].detach()
        elif hasattr(method, "posterior"):  # MSC's posterior mean from the object's points
            with torch.no_grad():
                z = method.posterior([ctx])[1][0]
        else:
            z = method.encode([ctx])[0][None].detach()
        x = torch.from_numpy(pts.astype(np.float32))[None].requires_grad_(True)
        with torch.enable_grad():
            f = module.decoder(z, x)
            g = gradient(f, x)
            off = offsurface_samples(x.detach(), method.options.offsurface or "paper")
            off.requires_grad_(True)
            eik = eikonal(gradient(module.decoder(z, off), off)).item()
            out = torch.from_numpy((pts + 0.05 * nrm).astype(np.float32))[None]
            blob = (module.decoder(z, out).detach()[0] < 0).numpy()
        f, g = f.detach()[0].abs(), g.detach()[0]
        err = (g - torch.from_numpy(nrm.astype(np.float32))).norm(dim=-1)
        parts = [f[thin], f[~thin], err[thin], err[~thin]]
        return (
            float(thin.float().mean()),
            *(float(v.mean()) if len(v) else math.nan for v in parts),
            eik,
            _blob(mesh, pts + 0.05 * nrm, blob),
        )
    # Occupancy methods: BCE on the object's own training queries, inside thin parts and elsewhere.
    from shapebench.geometry.nearest import kdtree
    from shapebench.preprocess.samples import occupancy_from_sdf

    q = (
        data.extra["occupancy"]
        if "occupancy" in data.extra
        else occupancy_from_sdf(data.extra["sdf"])
    )
    q = q[np.random.default_rng(0).choice(len(q), size=min(8192, len(q)), replace=False)]
    code = method.encode([ctx])[0]
    logits = torch.from_numpy(method.field(code)(q[:, :3]).astype(np.float32))
    label = torch.from_numpy(q[:, 3].astype(np.float32))
    bce = torch.nn.functional.binary_cross_entropy_with_logits(logits, label, reduction="none")
    _, nn = kdtree(pts).query(q[:, :3], k=1)
    in_thin = torch.from_numpy((q[:, 3] > 0.5) & thin.numpy()[nn])
    recall = (logits[in_thin] > method.level()).float()
    parts = [bce[in_thin], bce[~in_thin], recall]
    blob = method.field(code)(pts + 0.05 * nrm) > method.level()
    return (
        float(in_thin.float().mean()),
        *(float(v.mean()) if len(v) else math.nan for v in parts),
        math.nan,
        _blob(mesh, pts + 0.05 * nrm, blob),
    )


def _blob(mesh: trimesh.Trimesh, points: np.ndarray, called_inside: np.ndarray) -> float:
    """Share of ``points`` outside the object that the field calls inside."""
    outside = ~mesh.contains(points)
    return float(called_inside[outside].mean()) if outside.any() else math.nan


def losses(args) -> None:
    """Training-loss terms per category, on training objects and on validation objects."""
    resolved, dataset = resolve(args)
    method = resolved.cls(resolved.options)
    method.load_checkpoint(args.checkpoint)
    need = method.needs() - {s for s in method.needs() if s.value == "surface_points"}
    train = dataset.objects("train")
    index = {r.id: i for i, r in enumerate(train)}
    auto = hasattr(method.module, "latents")
    cats = args.categories.split(",")
    sdf = method.inside_is_negative
    head = (
        ("thin pts", "|f| thin", "|f| rest", "n-err thin", "n-err rest", "eikonal")
        if sdf
        else ("in-thin q", "bce thin", "bce rest", "thin recall", "", "")
    ) + ("+.05 in",)
    print(f"{args.method} seed {args.seed}: training-loss terms per category, 1000 own points")
    print(f"{'split':<10} {'category':<9} {'objs':>4} " + " ".join(f"{h:>10}" for h in head))
    for split in ("train", "validation"):
        refs = train if split == "train" else dataset.objects("validation")
        for cat in cats:
            rows = []
            for ref in [r for r in refs if r.category == cat][: args.objects]:
                mesh = unit_mesh(dataset, ref)
                data = dataset.load(ref, need)
                rng = np.random.default_rng(args.seed)
                pick = rng.choice(len(data.surface_points), size=1000, replace=False)
                pts = data.surface_points[pick].astype(np.float64)
                nrm = data.surface_normals[pick].astype(np.float64)
                code_index = index[ref.id] if (auto and split == "train") else None
                rows.append(_loss_rows(method, ref, data, mesh, pts, nrm, code_index, args))
            m = np.nanmean(np.array(rows, dtype=float), axis=0)
            print(f"{split:<10} {cat:<9} {len(rows):>4} " + " ".join(f"{v:>10.4f}" for v in m))


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("what", choices=["geometry", "field", "loss"])
    parser.add_argument("--method", "-m", default="msc")
    parser.add_argument("--checkpoint", type=Path)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--context", type=int, default=1000)
    parser.add_argument("--profile", default="standard")
    parser.add_argument("--categories", default="airplane,lamp,table,chair")
    parser.add_argument("--objects", type=int, default=2, help="validation objects per category")
    parser.add_argument("--thin", type=float, default=0.05)
    parser.add_argument("--pictures", default=None)
    parser.add_argument("--cache-dir", default=None)
    parser.add_argument("-O", action="append", default=[])
    parser.add_argument("-D", action="append", default=["test_per_category=2"])
    args = parser.parse_args(argv)
    tempfile.tempdir = tempfile.gettempdir()
    if args.what == "geometry":
        geometry(args)
        return
    if args.checkpoint is None:
        raise SystemExit(f"{args.what} needs --checkpoint")
    (field_probe if args.what == "field" else losses)(args)


if __name__ == "__main__":
    main()
