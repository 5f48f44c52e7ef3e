"""A CPU stand-in for SVRaster's CUDA extension (`svraster_cuda._C`), in plain torch.

It exists so that tools/svraster_step_dump.py can be dry-run on a machine without CUDA
(`--cpu`): the dump tool copies NVlabs/svraster's own Python package
(cuda/svraster_cuda/*.py) into a temporary folder beside this file's copy as `_C.py`, so
every line of SVRaster's Python runs as it is and only the kernels are replaced. On a GPU
machine the real extension is used and this file is not loaded.

Each function follows the CUDA source of NVlabs/svraster f0e7fa0 (cuda/src/*.cu), for what
the training step of `cfg/synthetic_nerf.yaml` needs:
  * rasterize_preprocess (preprocess.cu): near sphere on the centre, the projected box of
    the corners in front of the near plane rounded with lrint, the camera quadrants the
    corners touch;
  * rasterize_voxels (forward.cu renderCUDA): per pixel, the voxels whose box holds the
    pixel and whose quadrants hold the ray's, in the order rank octpath ^ quadrant table,
    ray-box [a, b], n_samp midpoint samples of the trilinear density through exp_linear_11,
    alpha = min(0.99999, 1 - exp(-vol)), skipped below 1e-5, stop once T < 1e-4, color
    C + T * bg, max_w the largest T * alpha per voxel;
  * rasterize_voxels_backward (backward.cu): the gradient of that forward by autograd, with
    the CUDA backward's two departures from it kept: alpha's clamp passes the gradient
    straight (dL/dI = dL/dalpha * exp(-vol)), and the per-point colour loss lambda_R_concen
    reaches only the colours; the subdivision priority is sum over pixels of
    |dL/dalpha * alpha|;
  * sh_compute / sh_compute_bw (sh_compute.cu): degree 0-3, colour clamped at 0 forward and
    the gradient passed straight through the clamp (the CUDA check is commented out);
  * gather_triinterp_geo_params(_bw), unbiased_adam_step, total_variation_bw,
    octpath_2_ijk / ijk_2_octpath.
  * the distortion loss (lambda_dist): the forward's mean contracted depth and the
    backward's DVGOv2 gradient on the blending weights, in walk order.
Depth, normal and ascending outputs are not implemented: asking for them raises (the
stand-in never returns a value it does not compute).
"""

import torch

MAX_NUM_LEVELS = 16
STEP_SZ_SCALE = 100.0
MAX_N_SAMP = 3
MAX_ALPHA = 0.99999
MIN_ALPHA = 0.00001
EARLY_STOP_T = 0.0001
SH_C0 = 0.28209479177387814
SH_C1 = 0.4886025119029199
SH_C2 = [1.0925484305920792, -1.0925484305920792, 0.31539156525252005,
         -1.0925484305920792, 0.5462742152960396]
SH_C3 = [-0.5900435899266435, 2.890611442640554, -0.4570457994644658,
         0.3731763325901154, -0.4570457994644658, 1.445305721320277,
         -0.5900435899266435]

IS_STAND_IN = True


def _order_table(q):
    t = 0
    for lv in range(MAX_NUM_LEVELS):
        t |= q << (3 * lv)
    return t


def octpath_2_ijk(octpath, octlevel):
    path = octpath.long().reshape(-1) >> (3 * (MAX_NUM_LEVELS - octlevel.long().reshape(-1)))
    ijk = torch.zeros([path.numel(), 3], dtype=torch.int64)
    for lv in range(MAX_NUM_LEVELS):
        bits = path & 7
        ijk[:, 0] |= ((bits >> 2) & 1) << lv
        ijk[:, 1] |= ((bits >> 1) & 1) << lv
        ijk[:, 2] |= (bits & 1) << lv
        path = path >> 3
    return ijk


def ijk_2_octpath(ijk, octlevel):
    ijk = ijk.long()
    path = torch.zeros([ijk.shape[0]], dtype=torch.int64)
    for lv in range(MAX_NUM_LEVELS):
        bits = (((ijk[:, 0] >> lv) & 1) << 2) | (((ijk[:, 1] >> lv) & 1) << 1) | ((ijk[:, 2] >> lv) & 1)
        path |= bits << (3 * lv)
    return (path << (3 * (MAX_NUM_LEVELS - octlevel.long().reshape(-1)))).reshape(-1, 1)


def _f(x):
    return torch.as_tensor(x, dtype=torch.float32)


def rasterize_preprocess(W, H, tanfovx, tanfovy, cx, cy, w2c, c2w, near,
                         octpath, vox_centers, vox_lengths, debug):
    """(n_duplicates [N] int32, geom [N, 5] int64: bbox xmin ymin xmax ymax, quadrant bits)."""
    c = vox_centers.float()
    r = 0.5 * vox_lengths.float().reshape(-1, 1)
    ro = c2w[:3, 3].float()
    N = c.shape[0]
    fx = W / (2.0 * tanfovx)
    fy = H / (2.0 * tanfovy)
    rel = c - ro
    keep = (rel * rel).sum(1) >= near * near
    cmin = torch.full([N, 2], 1e9)
    cmax = torch.full([N, 2], -1e9)
    quad = torch.zeros([N], dtype=torch.int64)
    for i in range(8):
        shift = _f([((i & 4) >> 2) * 2 - 1, ((i & 2) >> 1) * 2 - 1, (i & 1) * 2 - 1])
        wc = c + r * shift
        cc = wc @ w2c[:3, :3].float().T + w2c[:3, 3].float()
        front = cc[:, 2] >= near
        inv_z = 1.0 / cc[:, 2]
        coord = torch.stack([cc[:, 0] * inv_z, cc[:, 1] * inv_z], 1)
        cmin = torch.where(front[:, None], torch.minimum(cmin, coord), cmin)
        cmax = torch.where(front[:, None], torch.maximum(cmax, coord), cmax)
        q = ((wc[:, 0] < ro[0]).long() << 2) | ((wc[:, 1] < ro[1]).long() << 1) | (wc[:, 2] < ro[2]).long()
        quad = torch.where(front, quad | (1 << q), quad)
    bmin = torch.stack([(fx * cmin[:, 0] + (cx - 0.5)).clamp_min(0.0),
                        (fy * cmin[:, 1] + (cy - 0.5)).clamp_min(0.0)], 1)
    bmax = torch.stack([(fx * cmax[:, 0] + (cx - 0.5)).clamp_max(float(W)),
                        (fy * cmax[:, 1] + (cy - 0.5)).clamp_max(float(H))], 1)
    keep &= (bmin[:, 0] <= bmax[:, 0]) & (bmin[:, 1] <= bmax[:, 1])
    # lrintf: round half to even, as torch.round does.
    bbox = torch.cat([torch.round(bmin), torch.round(bmax)], 1).long()
    tiles = ((bbox[:, 2] // 16).clamp(0, (W + 15) // 16 - 1) - (bbox[:, 0] // 16).clamp(0, (W + 15) // 16 - 1) + 1) * \
            ((bbox[:, 3] // 16).clamp(0, (H + 15) // 16 - 1) - (bbox[:, 1] // 16).clamp(0, (H + 15) // 16 - 1) + 1)
    nquad = sum(((quad >> q) & 1) for q in range(8))
    n_dup = torch.where(keep, tiles * nquad, torch.zeros_like(tiles)).int()
    geom = torch.cat([bbox, quad[:, None]], 1)
    geom[~keep] = -1
    return n_dup, geom


def _pixel_rays(W, H, tanfovx, tanfovy, cx, cy, c2w):
    ys, xs = torch.meshgrid(torch.arange(H, dtype=torch.float32),
                            torch.arange(W, dtype=torch.float32), indexing="ij")
    d = torch.stack([(xs + 0.5 - cx) * 2.0 * tanfovx / W,
                     (ys + 0.5 - cy) * 2.0 * tanfovy / H,
                     torch.ones_like(xs)], -1).reshape(-1, 3)
    norm = d.norm(dim=1, keepdim=True)
    rd = (d @ c2w[:3, :3].float().T) / norm
    pix = torch.stack([xs, ys], -1).reshape(-1, 2).long()
    return rd, pix


def _hits(rd, pix, pq, ro, vox_centers, vox_lengths, geom, chunk=1024):
    """(pixel, voxel) pairs the walk visits before its alpha test: the pixel in the
    voxel's box, the ray's quadrant among the voxel's, the ray-box interval non-empty
    (cuda ray_aabb in float32); with the interval [a, b] of each pair."""
    bbox, quad = geom[:, :4], geom[:, 4]
    half = 0.5 * vox_lengths.float().reshape(1, -1, 1)
    dirc = (vox_centers.float() - ro)[None]
    ps, vs, As, Bs = [], [], [], []
    for s in range(0, rd.shape[0], chunk):
        px, q, r = pix[s:s + chunk], pq[s:s + chunk], rd[s:s + chunk]
        inb = (px[:, None, 0] >= bbox[None, :, 0]) & (px[:, None, 1] >= bbox[None, :, 1]) & \
              (px[:, None, 0] <= bbox[None, :, 2]) & (px[:, None, 1] <= bbox[None, :, 3]) & \
              (((quad[None, :] >> q[:, None]) & 1) == 1) & (quad[None, :] >= 0)
        rinv = (1.0 / r)[:, None]
        c0_ = (dirc - half) * rinv
        c1_ = (dirc + half) * rinv
        a = torch.minimum(c0_, c1_).amax(-1)
        b = torch.maximum(c0_, c1_).amin(-1)
        p_i, v_i = (inb & (a <= b)).nonzero(as_tuple=True)
        ps.append(p_i + s)
        vs.append(v_i)
        As.append(a[p_i, v_i])
        Bs.append(b[p_i, v_i])
    return torch.cat(ps), torch.cat(vs), torch.cat(As), torch.cat(Bs)


def _composite(n_samp, W, H, tanfovx, tanfovy, cx, cy, c2w, bg, octpath, vox_centers,
               vox_lengths, geos, rgbs, geom):
    """The per-pixel walk over its (pixel, voxel) pairs in depth order. Returns color
    [3,H,W], T [1,H,W], per blended pair its pixel, voxel and weight T*alpha, and per pair
    the walk tested (blended or not) its alpha and voxel."""
    rd, pix = _pixel_rays(W, H, tanfovx, tanfovy, cx, cy, c2w)
    ro = c2w[:3, 3].float()
    P, N = rd.shape[0], vox_centers.shape[0]
    pq = ((rd[:, 0] < 0).long() << 2) | ((rd[:, 1] < 0).long() << 1) | (rd[:, 2] < 0).long()
    p_i, v_i, a, b = _hits(rd, pix, pq, ro, vox_centers, vox_lengths, geom)
    # Depth order: within a pixel, the rank octpath ^ table[ray quadrant].
    ranks = torch.stack([octpath.reshape(-1).long() ^ _order_table(q) for q in range(8)])
    pos = ranks.argsort(1).argsort(1)
    srt = (p_i * N + pos[pq[p_i], v_i]).argsort()
    p_i, v_i, a, b = p_i[srt], v_i[srt], a[srt], b[srt]
    # Volume integral of the n_samp midpoint samples.
    L = vox_lengths.float().reshape(-1)[v_i]
    base = vox_centers.float()[v_i] - 0.5 * L[:, None]
    r = rd[p_i]
    g = geos[v_i]
    step = (b - a) / n_samp
    vol = torch.zeros_like(a)
    for k in range(n_samp):
        q = (ro + (a + (k + 0.5) * step)[:, None] * r - base) / L[:, None]
        wx = torch.stack([1 - q[:, 0], q[:, 0]], -1)
        wy = torch.stack([1 - q[:, 1], q[:, 1]], -1)
        wz = torch.stack([1 - q[:, 2], q[:, 2]], -1)
        w = (wx[:, :, None, None] * wy[:, None, :, None] * wz[:, None, None, :]).reshape(-1, 8)
        d = (w * g).sum(-1)
        dens = torch.where(d > 1.1, d, torch.exp(0.909090909091 * d - 0.904689820196))
        vol = vol + STEP_SZ_SCALE * step * dens
    raw = 1.0 - torch.exp(-vol)
    # The clamp at MAX_ALPHA passes the gradient straight (backward.cu: dL/dI = dL/dalpha
    # * exp(-vol)).
    alpha = raw + (raw.clamp(max=MAX_ALPHA) - raw).detach()
    use = alpha.detach() >= MIN_ALPHA
    # Each pixel's pairs into a row of a [P, K] matrix, in order, for the running product.
    counts = torch.bincount(p_i, minlength=P)
    K = max(int(counts.max()) if counts.numel() else 0, 1)
    starts = torch.cumsum(counts, 0) - counts
    slot = torch.arange(p_i.numel()) - starts[p_i]
    A = torch.zeros([P, K]).index_put((p_i, slot), torch.where(use, alpha, torch.zeros_like(alpha)))
    one_m = 1.0 - A
    Tex = torch.cat([torch.ones([P, 1]), torch.cumprod(one_m, 1)[:, :-1]], 1)
    live = Tex.detach() >= EARLY_STOP_T
    Wm = torch.where(live, Tex * A, torch.zeros_like(A))
    Tfin = torch.where(live, one_m, torch.ones_like(one_m)).prod(1)
    pt_w = Wm[p_i, slot]
    color = torch.zeros([P, 3]).index_add(0, p_i, pt_w[:, None] * rgbs[v_i]) + Tfin[:, None] * bg
    keep = use & live[p_i, slot]
    # Distortion (forward.cu Ddist; backward.cu's DVGOv2 form): per pixel the weights and
    # contracted midpoints in walk order, for the mean and the gradient surrogate.
    def contracted(x):
        return torch.where(x < 1.0, x, 2.0 - 1.0 / x)
    ad = torch.zeros([P, K]).index_put((p_i, slot), contracted(a))
    bd = torch.zeros([P, K]).index_put((p_i, slot), contracted(b))
    dist = {"W": Wm, "m": 0.5 * (ad + bd), "len": bd - ad}
    return (color.T.reshape(3, H, W), Tfin.reshape(1, H, W),
            p_i[keep], v_i[keep], pt_w[keep], alpha, v_i, dist)


def _distortion_surrogate(dist):
    """Per pixel, sum over its blended pairs of w_i * g_i with g_i (held constant) the
    gradient backward.cu adds to dL/dw_i: 2/3 w_i (b_i - a_i) + 2 (m_i (P_i - S_i) -
    (PM_i - SM_i)), P/S the weights before/after i in walk order, PM/SM with m; a, b,
    m on the contracted axis. Its gradient through w is the CUDA backward's."""
    Wm, m, ln = dist["W"], dist["m"], dist["len"]
    with torch.no_grad():
        w = Wm.detach()
        pre = torch.cumsum(w, 1) - w
        suf = w.sum(1, keepdim=True) - pre - w
        wm = w * m
        pre_m = torch.cumsum(wm, 1) - wm
        suf_m = wm.sum(1, keepdim=True) - pre_m - wm
        g = 0.6666666 * w * ln + 2.0 * (m * (pre - suf) - (pre_m - suf_m))
    return (Wm * g).sum()


def rasterize_voxels(n_samp, W, H, tanfovx, tanfovy, cx, cy, w2c, c2w, bg, need_depth,
                     need_distortion, need_normal, track_max_w, octpath, vox_centers,
                     vox_lengths, geos, rgbs, geom, debug):
    if need_depth or need_normal:
        raise NotImplementedError("the CPU stand-in renders colour, T and distortion only")
    with torch.no_grad():
        color, T, _, v, pt_w, _, _, dist = _composite(n_samp, W, H, tanfovx, tanfovy, cx, cy, c2w,
                                                      bg, octpath, vox_centers, vox_lengths,
                                                      geos, rgbs, geom)
    max_w = torch.empty(0)
    if track_max_w:
        max_w = torch.zeros([vox_centers.shape[0]]).scatter_reduce(
            0, v, pt_w, reduce="amax").reshape(-1, 1)
    empty = torch.empty(0)
    depth = empty
    if need_distortion:
        # out_depth channel 1: the mean contracted depth; channels 0 and 2 (mean and median
        # depth) are written only with need_depth, and stay 0 as torch::full leaves them.
        depth = torch.zeros([3, H, W])
        depth[1] = (dist["W"] * dist["m"]).sum(1).reshape(H, W)
    return 0, empty, empty, color, depth, empty, T, max_w


def rasterize_voxels_backward(num_rendered, n_samp, W, H, tanfovx, tanfovy, cx, cy, w2c, c2w,
                              bg, octpath, vox_centers, vox_lengths, geos, rgbs, geom,
                              binning, img, out_T, dL_dcolor, dL_ddepth, dL_dnormal, dL_dT,
                              lambda_R_concen, gt_color, lambda_ascending, lambda_dist,
                              need_depth, need_normal, out_depth, out_normal, debug):
    if lambda_ascending > 0 or need_depth or need_normal:
        raise NotImplementedError("the CPU stand-in's backward has colour, T, distortion and "
                                  "R_concen only")
    g = geos.detach().clone().requires_grad_()
    c = rgbs.detach().clone().requires_grad_()
    with torch.enable_grad():
        color, T, p, v, pt_w, all_alpha, v_all, dist = _composite(
            n_samp, W, H, tanfovx, tanfovy, cx, cy, c2w, bg, octpath, vox_centers, vox_lengths,
            g, c, geom)
        all_alpha.retain_grad()
        obj = (color * dL_dcolor).sum()
        if lambda_dist > 0:
            obj = obj + lambda_dist / (W * H) * _distortion_surrogate(dist)
        if dL_dT is not None and dL_dT.numel():
            obj = obj + (T * dL_dT).sum()
        if lambda_R_concen > 0:
            gt = gt_color.reshape(3, -1).T
            err = ((c[v] - gt[p]) ** 2).sum(-1)
            obj = obj + lambda_R_concen / (W * H) * (pt_w.detach() * err).sum()
        obj.backward()
    # The priority sums |dL/dalpha * alpha| over the blended pairs (grad_pack[11]); the
    # others have a zero alpha gradient.
    n = vox_centers.shape[0]
    keep_grad = all_alpha.grad if all_alpha.grad is not None else torch.zeros_like(all_alpha)
    prio = torch.zeros([n]).index_add(0, v_all, (keep_grad * all_alpha.detach()).abs()).reshape(-1, 1)
    zero = lambda t: torch.zeros_like(t) if t.grad is None else t.grad
    return zero(g), zero(c), prio


def _sh_basis(deg, d):
    x, y, z = d[:, 0], d[:, 1], d[:, 2]
    out = []
    if deg > 0:
        out += [-SH_C1 * y, SH_C1 * z, -SH_C1 * x]
    if deg > 1:
        xx, yy, zz, xy, yz, xz = x * x, y * y, z * z, x * y, y * z, x * z
        out += [SH_C2[0] * xy, SH_C2[1] * yz, SH_C2[2] * (2.0 * zz - xx - yy),
                SH_C2[3] * xz, SH_C2[4] * (xx - yy)]
    if deg > 2:
        out += [SH_C3[0] * y * (3.0 * xx - yy), SH_C3[1] * xy * z,
                SH_C3[2] * y * (4.0 * zz - xx - yy), SH_C3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * yy),
                SH_C3[4] * x * (4.0 * zz - xx - yy), SH_C3[5] * z * (xx - yy),
                SH_C3[6] * x * (xx - 3.0 * yy)]
    return torch.stack(out, 1) if out else torch.zeros([d.shape[0], 0])


def _sh_rgb(deg, idx, vox_centers, cam_pos, sh0, shs):
    d = vox_centers[idx].float() - cam_pos.float()
    d = d / d.norm(dim=1, keepdim=True)
    basis = _sh_basis(deg, d)                               # [n, M-1 used]
    res = SH_C0 * sh0[idx]
    if basis.shape[1]:
        res = res + (basis[:, :, None] * shs[idx][:, :basis.shape[1]]).sum(1)
    return res + 0.5


def sh_compute(deg, idx, vox_centers, cam_pos, sh0, shs):
    if idx.numel() == 0:
        idx = torch.arange(sh0.shape[0])
    out = torch.zeros_like(sh0)
    out[idx] = _sh_rgb(deg, idx, vox_centers, cam_pos, sh0.detach(), shs.detach()).clamp_min(0.0)
    return out


def sh_compute_bw(deg, M, idx, vox_centers, cam_pos, rgbs, dL_drgbs):
    # The gradient passes straight through the clamp at 0; it depends only on directions.
    n = rgbs.shape[0]
    if idx.numel() == 0:
        idx = torch.arange(n)
    d_sh0 = torch.zeros([n, 3])
    d_shs = torch.zeros([n, M - 1, 3])
    d = vox_centers[idx].float() - cam_pos.float()
    d = d / d.norm(dim=1, keepdim=True)
    g = dL_drgbs[idx]
    d_sh0[idx] = SH_C0 * g
    basis = _sh_basis(deg, d)
    if basis.shape[1]:
        d_shs[idx, :basis.shape[1]] = basis[:, :, None] * g[:, None]
    return d_sh0, d_shs


def gather_triinterp_geo_params(vox_key, care_idx, grid_pts):
    out = torch.zeros([vox_key.shape[0], 8])
    out[care_idx] = grid_pts.reshape(-1)[vox_key[care_idx]]
    return out


def gather_triinterp_geo_params_bw(vox_key, care_idx, num_grid_pts, dL_dgeo_params):
    out = torch.zeros([num_grid_pts, 1])
    out.reshape(-1).index_add_(0, vox_key[care_idx].reshape(-1),
                               dL_dgeo_params[care_idx].reshape(-1))
    return out


def unbiased_adam_step(sparse, param, grad, exp_avg, exp_avg_sq, step, lr, beta1, beta2, eps):
    # adam_step.cu: the bias corrections in double, the update in float (lerp with fma).
    bc1 = 1.0 - beta1 ** step
    bc2 = 1.0 - beta2 ** step
    step_size = lr / bc1
    rs = bc2 ** -0.5
    m = exp_avg * beta1 + grad * (1.0 - beta1)
    v = exp_avg_sq * beta2 + grad * grad * (1.0 - beta2)
    upd = step_size * (m / (v.sqrt() * rs + eps))
    mask = (grad != 0) if sparse else torch.ones_like(grad, dtype=torch.bool)
    param.data[mask] -= upd[mask]
    exp_avg[mask] = m[mask]
    exp_avg_sq[mask] = v[mask]


def total_variation_bw(grid_pts, vox_key, weight, vox_size_inv, no_tv_s, tv_sparse, grid_pts_grad):
    if tv_sparse:
        raise NotImplementedError("the CPU stand-in has the dense TV only")
    C = grid_pts.shape[1]
    v = grid_pts.detach()[vox_key]                          # [N, 8, C]
    w = torch.full([vox_key.shape[0], 1, 1], float(weight))
    if not no_tv_s:
        w = w * 0.01 * vox_size_inv.reshape(-1, 1, 1)
    g = torch.zeros_like(v)
    for i in range(8):
        for bit in (1, 2, 4):
            g[:, i] += (v[:, i] > v[:, i ^ bit]).float() * 2 - 1
    grid_pts_grad.index_add_(0, vox_key.reshape(-1), (w * g).reshape(-1, C))
