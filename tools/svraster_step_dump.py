#!/usr/bin/env python3
"""Runs training steps of the official SVRaster on a fixed model and writes every tensor
they compute, for the step-level parity test (tests/parity/, issue 60).

    svraster_step_dump.py --data DATASET (--model MODEL.pt | --init) --out DIR
        [--svr SVRASTER_SRC] [--cfg cfg/synthetic_nerf.yaml] [--sche_mult M]
        [--iteration N] [--views 3,7] [--ss 1.0,1.2] [--adapt] [--cpu] [--set key=value ...]

It loads MODEL.pt (SVRaster's own checkpoint layout, SVInOut.save; tools/svraster_checkpoint.py
writes one from a model of ours) into SVRaster's SparseVoxelModel, or with --init builds
SVRaster's initial model as train.py does (main-region bound, model_init on the training
cameras) and writes its layout as init.{octpath,octlevel} (step.json "init": the bound,
scene centre and extents, the parameters' values; and every training camera), builds SVRaster's data
pack, config, optimizer and learning-rate schedule exactly as train.py does, and runs
len(--views) consecutive iterations from iteration N, each on the given training view and
supersampling factor (train.py draws those at random; here they are fixed). Each
iteration's body is train.py's lines for the terms the config enables (photo, SSIM,
T concentration, T inside, mask, TV, Adam); a config that enables a term not copied here is
refused. With --adapt, the adaptive step after the last iteration runs too
(compute_training_stat, prune, subdivide), wherever the schedule puts one or not.

Writes DIR/step.safetensors (float32, int64 and uint8 tensors; names in DIR/step.json) and
DIR/step.json: the settings, each iteration's camera, view name, lrs, Adam step count and
loss terms. Per iteration i (0-based): i.gt, i.color, i.raw_T, i.grad.{geo,sh0,shs} (after
TV; i.grad.geo_render before it), i.subdiv_p (the priority accumulated by then),
i.param.{geo,sh0,shs} and i.adam.{geo,sh0,shs}.{m,v} after the optimizer step. With
--adapt: adapt.max_w, adapt.min_samp_interval, adapt.prune_mask, adapt.priority,
adapt.valid, adapt.subdivide_mask and the layout after it (adapt.octpath, adapt.octlevel,
adapt.grid_pts_key, adapt.param.{geo,sh0,shs}); step.json then lists every training
camera too (the statistics render them all).

--svr is NVlabs/svraster's checkout (default ../shared/gpu/svr/src beside this repo). On a
GPU machine its CUDA extension `svraster_cuda` must be importable (../shared/gpu/svr/run_svr.sh
build puts it in /tmp/site). --cpu runs without CUDA: SVRaster's Python package is copied
into a temporary folder with tools/svraster_cpu/_C.py (a torch re-implementation of the
kernels) as its extension, and `cuda` tensors are made on the CPU; that is a dry run of this
tool and a second implementation to compare with, not SVRaster's kernels.
"""

import argparse
import json
import os
import shutil
import struct
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))


def parse_args():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--data", required=True, help="dataset folder SVRaster reads (NeRF JSON or COLMAP)")
    p.add_argument("--model", help="SVRaster checkpoint (.pt) to start from")
    p.add_argument("--init", action="store_true",
                   help="start from SVRaster's own initial model instead (train.py's model_init "
                        "on the data's training cameras), and write it as init.*")
    p.add_argument("--out", required=True, help="output folder (made; must not exist)")
    p.add_argument("--svr", default=os.path.join(HERE, "..", "..", "shared", "gpu", "svr", "src"))
    p.add_argument("--cfg", default="cfg/synthetic_nerf.yaml", help="config file, relative to --svr")
    p.add_argument("--sche_mult", type=float, default=1.0)
    p.add_argument("--iteration", type=int, default=1001, help="1-based iteration of the first step")
    p.add_argument("--views", default=None,
                   help="training view index per step, comma-separated (default 0; none with --init)")
    p.add_argument("--ss", default="", help="supersampling per step (default 1.0 each); "
                   "train.py uses 1.0 up to iteration 1000")
    p.add_argument("--adapt", action="store_true", help="also run the adaptive step after the last one")
    p.add_argument("--cpu", action="store_true", help="dry run on the CPU stand-in kernels")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="config override as train.py's command line takes it, e.g. --set lambda_ssim=0")
    return p.parse_args()


def die(msg):
    print(f"svraster_step_dump: {msg}", file=sys.stderr)
    sys.exit(1)


def install_cpu_stand_in(svr):
    """svraster_cuda from SVRaster's own Python files with our CPU kernels as _C, and torch
    told to make `cuda` tensors on the CPU."""
    import torch
    pkg_src = os.path.join(svr, "cuda", "svraster_cuda")
    tmp = tempfile.mkdtemp(prefix="svr_cpu_")
    dst = os.path.join(tmp, "svraster_cuda")
    shutil.copytree(pkg_src, dst)
    shutil.copy(os.path.join(HERE, "svraster_cpu", "_C.py"), os.path.join(dst, "_C.py"))
    sys.path.insert(0, tmp)
    sys.path.append(os.path.join(svr, "..", "stubs"))  # fused_ssim in torch, pycolmap stub

    def cpu(dev):
        return "cpu" if dev is not None and str(dev).startswith("cuda") else dev

    def wrap(f):
        def g(*a, **k):
            if "device" in k:
                k["device"] = cpu(k["device"])
            return f(*a, **k)
        return g

    for name in ["zeros", "ones", "empty", "full", "arange", "rand", "randn", "randint", "tensor",
                 "linspace", "eye", "as_tensor", "zeros_like", "ones_like", "empty_like",
                 "full_like", "rand_like", "randn_like"]:
        setattr(torch, name, wrap(getattr(torch, name)))
    orig_to = torch.Tensor.to

    def to(self, *a, **k):
        a = tuple(cpu(x) if isinstance(x, (str, torch.device)) else x for x in a)
        if "device" in k:
            k["device"] = cpu(k["device"])
        return orig_to(self, *a, **k)

    torch.Tensor.to = to
    torch.Tensor.cuda = lambda self, *a, **k: self

    class Event:
        def __init__(self, *a, **k):
            pass

        def record(self):
            pass

        def elapsed_time(self, other):
            return 0.0

    torch.cuda.Event = Event
    torch.cuda.synchronize = lambda *a, **k: None
    torch.cuda.empty_cache = lambda *a, **k: None
    torch.cuda.set_device = lambda *a, **k: None
    return tmp


def write_safetensors(path, tensors):
    """The safetensors layout (8-byte little-endian header length, JSON header, data), with
    the standard library: F32, I64 and U8 only."""
    import torch
    kinds = {torch.float32: "F32", torch.int64: "I64", torch.uint8: "U8"}
    header, blobs, off = {}, [], 0
    for name in sorted(tensors):
        t = tensors[name].detach().cpu().contiguous()
        if t.dtype == torch.bool:
            t = t.to(torch.uint8)
        if t.dtype not in kinds:
            t = t.to(torch.float32) if t.is_floating_point() else t.to(torch.int64)
        b = t.numpy().tobytes()
        header[name] = {"dtype": kinds[t.dtype], "shape": list(t.shape), "data_offsets": [off, off + len(b)]}
        blobs.append(b)
        off += len(b)
    h = json.dumps(header, separators=(",", ":")).encode()
    h += b" " * ((8 - len(h) % 8) % 8)
    with open(path + ".tmp", "wb") as f:
        f.write(struct.pack("<Q", len(h)))
        f.write(h)
        for b in blobs:
            f.write(b)
    os.replace(path + ".tmp", path)


def apply_sche_mult(cfg, m):
    """train.py's `--sche_mult` block (its __main__), unchanged."""
    if m == 1:
        return
    for key in ['geo_lr', 'sh0_lr', 'shs_lr']:
        cfg.optimizer[key] /= m
    cfg.optimizer.lr_decay_ckpt = [round(v * m) if v > 0 else v for v in cfg.optimizer.lr_decay_ckpt]
    for key in ['dist_from', 'tv_from', 'tv_until', 'n_dmean_from', 'n_dmean_end',
                'n_dmed_from', 'n_dmed_end', 'depthanythingv2_from', 'depthanythingv2_end',
                'mast3r_metric_depth_from', 'mast3r_metric_depth_end']:
        cfg.regularizer[key] = round(cfg.regularizer[key] * m)
    for key in ['n_iter', 'adapt_from', 'adapt_every', 'prune_until', 'subdivide_until',
                'subdivide_all_until']:
        cfg.procedure[key] = round(cfg.procedure[key] * m)
    cfg.procedure.reset_sh_ckpt = [round(v * m) if v > 0 else v for v in cfg.procedure.reset_sh_ckpt]


def main():
    args = parse_args()
    svr = os.path.abspath(args.svr)
    if not os.path.isfile(os.path.join(svr, "train.py")):
        die(f"{svr} is not an SVRaster checkout (no train.py); pass --svr")
    if (args.model is None) == (not args.init):
        die("give either --model MODEL.pt or --init")
    for what, path in (("--data", args.data), ("--model", args.model)):
        if path is not None and not os.path.exists(path):
            die(f"{what} {path} does not exist")
    if os.path.exists(args.out):
        die(f"--out {args.out} exists; name a new folder")
    if args.views is None:
        args.views = "" if args.init else "0"
    views = [int(v) for v in args.views.split(",") if v != ""]
    ss = [float(s) for s in args.ss.split(",")] if args.ss else [1.0] * len(views)
    if len(ss) != len(views):
        die(f"--ss has {len(ss)} values for {len(views)} --views")
    data = os.path.abspath(args.data)
    model = os.path.abspath(args.model) if args.model else None
    out = os.path.abspath(args.out)

    tmp = install_cpu_stand_in(svr) if args.cpu else None
    sys.path.insert(0, svr)
    os.chdir(svr)
    import numpy as np
    import torch
    from src.config import cfg, update_config
    from src.utils.system_utils import seed_everything
    from src.utils import loss_utils
    from src.dataloader.data_pack import DataPack
    from src.utils.bounding_utils import decide_main_bounding
    from src.sparse_voxel_model import SparseVoxelModel
    import svraster_cuda

    update_config([args.cfg], _cmd_list(args.set))
    apply_sche_mult(cfg, args.sche_mult)
    cfg.procedure.sche_mult = args.sche_mult
    seed_everything(cfg.procedure.seed)
    R = cfg.regularizer
    unsupported = {
        "use_l1": R.use_l1, "use_huber": R.use_huber, "lambda_sparse_depth": R.lambda_sparse_depth,
        "lambda_depthanythingv2": R.lambda_depthanythingv2,
        "lambda_mast3r_metric_depth": R.lambda_mast3r_metric_depth, "rand_bg": R.rand_bg,
        "auto_exposure.enable": cfg.auto_exposure.enable,
    }
    bad = [k for k, v in unsupported.items() if v]
    if bad:
        die(f"the config enables {', '.join(bad)}, which this tool does not copy from train.py")

    data_pack = DataPack(
        source_path=data, image_dir_name=cfg.data.image_dir_name,
        res_downscale=cfg.data.res_downscale, res_width=cfg.data.res_width,
        skip_blend_alpha=cfg.data.skip_blend_alpha, alpha_is_white=cfg.model.white_background,
        data_device=cfg.data.data_device, use_test=cfg.data.eval, test_every=cfg.data.test_every)
    tr_cams = data_pack.get_train_cameras()
    for v in views:
        if not 0 <= v < len(tr_cams):
            die(f"--views {v}: the data has {len(tr_cams)} training views")

    class Store(dict):
        # Copies at once: Adam and the next step update parameters and moments in place.
        def __setitem__(self, k, v):
            super().__setitem__(k, v.detach().clone())

    voxel_model = SparseVoxelModel(
        n_samp_per_vox=cfg.model.n_samp_per_vox, sh_degree=cfg.model.sh_degree, ss=cfg.model.ss,
        white_background=cfg.model.white_background, black_background=cfg.model.black_background)
    tensors = Store()
    init = None
    if args.init:
        # train.py:70-103, as it is.
        bounding = decide_main_bounding(
            bound_mode=cfg.bounding.bound_mode, forward_dist_scale=cfg.bounding.forward_dist_scale,
            pcd_density_rate=cfg.bounding.pcd_density_rate, bound_scale=cfg.bounding.bound_scale,
            tr_cams=tr_cams, pcd=data_pack.point_cloud, suggested_bounding=data_pack.suggested_bounding)
        voxel_model.model_init(
            bounding=bounding, outside_level=cfg.bounding.outside_level,
            init_n_level=cfg.init.init_n_level, init_out_ratio=cfg.init.init_out_ratio,
            sh_degree_init=cfg.init.sh_degree_init, geo_init=cfg.init.geo_init,
            sh0_init=cfg.init.sh0_init, shs_init=cfg.init.shs_init, cameras=tr_cams)
        tensors["init.octpath"] = voxel_model.octpath
        tensors["init.octlevel"] = voxel_model.octlevel.to(torch.int64)
        # The parameters are constants (model_init's torch.full): recorded as values.
        vals = {n: torch.unique(getattr(voxel_model, a).detach()).cpu().tolist()
                for n, a in (("geo", "_geo_grid_pts"), ("sh0", "_sh0"), ("shs", "_shs"))}
        init = {"bounding": torch.as_tensor(bounding).tolist(),
                "scene_center": voxel_model.scene_center.tolist(),
                "scene_extent": float(voxel_model.scene_extent),
                "inside_extent": float(voxel_model.inside_extent),
                "active_sh_degree": voxel_model.active_sh_degree,
                "voxels": voxel_model.num_voxels, "grid_points": voxel_model.num_grid_pts,
                "values": vals}
        print(f"init: {voxel_model.num_voxels} voxels, {voxel_model.num_grid_pts} grid points, "
              f"scene {init['scene_center']} extent {init['scene_extent']}")
    else:
        voxel_model.load(model)

    def camera_json(cam):
        return {"width": cam.image_width, "height": cam.image_height,
                "tanfovx": float(cam.tanfovx), "tanfovy": float(cam.tanfovy),
                "cx": float(cam.cx), "cy": float(cam.cy), "near": float(cam.near),
                "c2w": cam.c2w.cpu().tolist(), "image_name": cam.image_name}

    def create_trainer():
        optimizer = svraster_cuda.sparse_adam.SparseAdam(
            [{'params': [voxel_model._geo_grid_pts], 'lr': cfg.optimizer.geo_lr},
             {'params': [voxel_model._sh0], 'lr': cfg.optimizer.sh0_lr},
             {'params': [voxel_model._shs], 'lr': cfg.optimizer.shs_lr}],
            betas=(cfg.optimizer.optim_beta1, cfg.optimizer.optim_beta2), eps=cfg.optimizer.optim_eps)
        scheduler = torch.optim.lr_scheduler.MultiStepLR(
            optimizer, milestones=cfg.optimizer.lr_decay_ckpt, gamma=cfg.optimizer.lr_decay_mult)
        return optimizer, scheduler

    optimizer, scheduler = create_trainer()
    # The learning rates of iteration N: train.py steps the scheduler once per iteration.
    for _ in range(args.iteration - 1):
        scheduler.step()

    steps = []
    for i, (view, s) in enumerate(zip(views, ss)):
        iteration = args.iteration + i
        if iteration % 1000 == 0:
            voxel_model.sh_degree_add1()
        if iteration in cfg.procedure.reset_sh_ckpt:
            voxel_model.reset_sh_from_cameras(tr_cams)
        tr_render_opt = {
            'track_max_w': False, 'lambda_R_concen': R.lambda_R_concen, 'output_T': False,
            'output_depth': False, 'ss': 1.0, 'rand_bg': R.rand_bg,
            'use_auto_exposure': cfg.auto_exposure.enable,
        }
        if iteration > 1000:
            if R.ss_aug_max > 1:
                tr_render_opt['ss'] = s          # train.py: np.random.uniform(1, ss_aug_max)
            else:
                tr_render_opt.pop('ss')
        elif s != 1.0:
            die(f"iteration {iteration} renders at ss 1 in train.py; --ss {s} cannot be")
        need_nd = R.lambda_normal_dmean > 0 and iteration >= R.n_dmean_from and iteration <= R.n_dmean_end
        need_nmed = R.lambda_normal_dmed > 0 and iteration >= R.n_dmed_from and iteration <= R.n_dmed_end
        tr_render_opt['output_T'] = R.lambda_T_concen > 0 or R.lambda_T_inside > 0 or R.lambda_mask > 0 or need_nd
        tr_render_opt['output_normal'] = need_nd or need_nmed
        tr_render_opt['output_depth'] = need_nd or need_nmed
        if iteration >= R.dist_from and R.lambda_dist:
            tr_render_opt['lambda_dist'] = R.lambda_dist
        if iteration >= R.ascending_from and R.lambda_ascending:
            tr_render_opt['lambda_ascending'] = R.lambda_ascending
        cam = tr_cams[view]
        gt_image = cam.image.cuda()
        if R.lambda_R_concen > 0:
            tr_render_opt['gt_color'] = gt_image

        nd_loss = loss_utils.NormalDepthConsistencyLoss(
            iter_from=R.n_dmean_from, iter_end=R.n_dmean_end, ks=R.n_dmean_ks, tol_deg=R.n_dmean_tol_deg)
        nmed_loss = loss_utils.NormalMedianConsistencyLoss(iter_from=R.n_dmed_from, iter_end=R.n_dmed_end)

        render_pkg = voxel_model.render(cam, **tr_render_opt)
        render_image = render_pkg['color']
        terms = {}
        mse = loss_utils.l2_loss(render_image, gt_image)
        terms['mse'] = mse
        loss = R.lambda_photo * mse
        if R.lambda_mask:
            terms['mask'] = loss_utils.l2_loss(render_pkg['T'], 1 - cam.mask.cuda())
            loss += R.lambda_mask * terms['mask']
        if R.lambda_ssim:
            terms['ssim'] = loss_utils.fast_ssim_loss(render_image, gt_image)
            loss += R.lambda_ssim * terms['ssim']
        if R.lambda_T_concen:
            terms['T_concen'] = loss_utils.prob_concen_loss(render_pkg['raw_T'])
            loss += R.lambda_T_concen * terms['T_concen']
        if R.lambda_T_inside:
            terms['T_inside'] = render_pkg['raw_T'].square().mean()
            loss += R.lambda_T_inside * terms['T_inside']
        if need_nd:
            terms['normal_dmean'] = nd_loss(cam, render_pkg, iteration)
            loss += R.lambda_normal_dmean * terms['normal_dmean']
        if need_nmed:
            terms['normal_dmed'] = nmed_loss(cam, render_pkg, iteration)
            loss += R.lambda_normal_dmed * terms['normal_dmed']

        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        geo_render = voxel_model._geo_grid_pts.grad.clone()
        tv = R.lambda_tv_density and R.tv_from <= iteration <= R.tv_until
        if tv:
            voxel_model.apply_tv_on_density_field(R.lambda_tv_density)
        lrs = [g['lr'] for g in optimizer.param_groups]
        optimizer.step()
        adam_steps = [optimizer.state[g['params'][0]].get('step', 0) for g in optimizer.param_groups]

        p = f"{i}."
        tensors[p + "gt"] = gt_image
        tensors[p + "color"] = render_image
        if render_pkg['raw_T'] is not None:
            tensors[p + "raw_T"] = render_pkg['raw_T']
        tensors[p + "grad.geo_render"] = geo_render
        tensors[p + "grad.geo"] = voxel_model._geo_grid_pts.grad
        tensors[p + "grad.sh0"] = voxel_model._sh0.grad
        tensors[p + "grad.shs"] = voxel_model._shs.grad
        tensors[p + "subdiv_p"] = voxel_model._subdiv_p.grad
        for name, param in (("geo", voxel_model._geo_grid_pts), ("sh0", voxel_model._sh0),
                            ("shs", voxel_model._shs)):
            tensors[p + "param." + name] = param
            st = optimizer.state[param]
            tensors[p + f"adam.{name}.m"] = st['exp_avg']
            tensors[p + f"adam.{name}.v"] = st['exp_avg_sq']
        steps.append({
            "iteration": iteration, "view": view, "image_name": cam.image_name, "ss": s,
            "render_size": [round(cam.image_width * tr_render_opt.get('ss', voxel_model.ss)),
                            round(cam.image_height * tr_render_opt.get('ss', voxel_model.ss))],
            "active_sh_degree": voxel_model.active_sh_degree,
            "lr": {"geo": lrs[0], "sh0": lrs[1], "shs": lrs[2]},
            "adam_step": adam_steps, "tv": bool(tv),
            "camera": camera_json(cam),
            "losses": {k: float(v) for k, v in terms.items()}, "loss": float(loss),
            "render_opt": {k: (v if isinstance(v, (bool, int, float, str)) else str(type(v)))
                           for k, v in tr_render_opt.items() if k != 'gt_color'},
        })
        print(f"step {i}: iteration {iteration} view {view} ({cam.image_name}) ss {s} "
              f"loss {float(loss):.6f} " + " ".join(f"{k} {float(v):.6f}" for k, v in terms.items()))
        scheduler.step()

    adapt = None
    if args.adapt:
        iteration = args.iteration + len(views) - 1
        P = cfg.procedure
        stat_pkg = voxel_model.compute_training_stat(camera_lst=tr_cams)
        prune_thres = float(np.interp(iteration, xp=[P.adapt_from, P.prune_until],
                                      fp=[P.prune_thres_init, P.prune_thres_final]))
        prune_mask = (stat_pkg['max_w'] < prune_thres).squeeze(1)
        tensors["adapt.max_w"] = stat_pkg['max_w']
        tensors["adapt.min_samp_interval"] = stat_pkg['min_samp_interval']
        tensors["adapt.prune_mask"] = prune_mask
        tensors["adapt.subdiv_p"] = voxel_model.subdivision_priority
        n0 = voxel_model.num_voxels
        voxel_model.pruning(prune_mask)
        n1 = voxel_model.num_voxels
        min_samp_interval = stat_pkg['min_samp_interval'][~prune_mask]
        size_thres = min_samp_interval * P.subdivide_samp_thres
        large_enough = (voxel_model.vox_size * 0.5 > size_thres).squeeze(1)
        non_finest = voxel_model.octlevel.squeeze(1) < svraster_cuda.meta.MAX_NUM_LEVELS
        valid_mask = large_enough & non_finest
        priority = voxel_model.subdivision_priority.squeeze(1) * valid_mask
        if iteration <= P.subdivide_all_until:
            thres = -1
        else:
            thres = priority.quantile(1 - P.subdivide_prop)
        subdivide_mask = (priority > thres) & valid_mask
        max_n_subdiv = round((P.subdivide_max_num - voxel_model.num_voxels) / 7)
        if subdivide_mask.sum() > max_n_subdiv:
            n_removed = subdivide_mask.sum() - max_n_subdiv
            subdivide_mask &= (priority > priority[subdivide_mask].sort().values[n_removed - 1])
        tensors["adapt.priority"] = priority
        tensors["adapt.valid"] = valid_mask
        tensors["adapt.subdivide_mask"] = subdivide_mask
        voxel_model.subdividing(subdivide_mask)
        tensors["adapt.octpath"] = voxel_model.octpath
        tensors["adapt.octlevel"] = voxel_model.octlevel.to(torch.int64)
        tensors["adapt.grid_pts_key"] = voxel_model.grid_pts_key
        tensors["adapt.param.geo"] = voxel_model._geo_grid_pts
        tensors["adapt.param.sh0"] = voxel_model._sh0
        tensors["adapt.param.shs"] = voxel_model._shs
        adapt = {"iteration": iteration, "prune_thres": prune_thres,
                 "subdivide_thres": float(thres), "voxels": [n0, n1, voxel_model.num_voxels],
                 "pruned": int(prune_mask.sum()), "subdivided": int(subdivide_mask.sum())}
        print(f"adapt @ {iteration}: {n0} → {n1} (pruned, thres {prune_thres:.5f}) → "
              f"{voxel_model.num_voxels} voxels (subdivided {int(subdivide_mask.sum())})")

    os.makedirs(out)
    write_safetensors(os.path.join(out, "step.safetensors"), tensors)
    meta = {
        "tool": "tools/svraster_step_dump.py", "argv": sys.argv[1:],
        "kernels": "cpu stand-in (tools/svraster_cpu/_C.py)" if args.cpu else "svraster_cuda",
        "svraster_commit": _upstream_commit(svr), "torch": torch.__version__,
        "cfg_file": args.cfg, "sche_mult": args.sche_mult,
        "config": {k: dict(v) for k, v in cfg.items()},
        "model": os.path.basename(model) if model else None, "init": init,
        "voxels": int(n0 if adapt else voxel_model.num_voxels),
        "steps": steps, "adapt": adapt, "tensors": sorted(tensors),
        "train_cameras": [camera_json(c) for c in tr_cams] if adapt or init else None,
    }
    with open(os.path.join(out, "step.json"), "w") as f:
        json.dump(meta, f, indent=1, default=str)
    if tmp:
        shutil.rmtree(tmp, ignore_errors=True)
    print(f"wrote {out}/step.safetensors ({len(tensors)} tensors) and step.json")


def _cmd_list(sets):
    out = []
    for kv in sets:
        if "=" not in kv:
            die(f"--set {kv}: expected KEY=VALUE")
        k, v = kv.split("=", 1)
        out += [f"--{k}"] + v.split()
    return out


def _upstream_commit(svr):
    for f in ("UPSTREAM_COMMIT",):
        p = os.path.join(svr, f)
        if os.path.isfile(p):
            return open(p).read().strip()
    return "unknown"


if __name__ == "__main__":
    main()
