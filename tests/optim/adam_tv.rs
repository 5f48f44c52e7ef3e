use super::*;

#[test]
fn adam_matches_f64_reference() {
    let ctx = context();
    let adam = Adam::new(&ctx).unwrap();
    let cfg = AdamConfig::default();
    assert_eq!(
        cfg,
        AdamConfig {
            lr: 1e-3,
            beta1: 0.1,
            beta2: 0.99,
            eps: 1e-15,
            skip_zero: false,
        }
    );
    let mut rng = Rng(0xada0);
    let n = 100_003usize;
    // Special elements: 0 and 1 get ±1e20 every step (v saturates at f32::MAX from step
    // 4 on), 2 gets exactly 0 every step.
    const SAT: [usize; 2] = [0, 1];
    const ZERO: usize = 2;
    let p0: Vec<f32> = (0..n)
        .map(|i| {
            if i % 97 == 0 {
                rng.range(-1e4, 1e4) as f32
            } else {
                rng.range(-3.0, 3.0) as f32
            }
        })
        .collect();
    let bufs = AdamBufs::new(&ctx, &p0, &vec![0.0; n], &vec![0.0; n]);
    let mut refs: Vec<RefAdam> = p0
        .iter()
        .map(|&p| RefAdam {
            p: f64::from(p),
            ..Default::default()
        })
        .collect();
    let mut worst = (0.0f64, 0.0f64, 0.0f64);
    for t in 1..=5u32 {
        let mut grads: Vec<f32> = (0..n).map(|_| random_grad(&mut rng)).collect();
        grads[SAT[0]] = 1e20;
        grads[SAT[1]] = -1e20;
        grads[ZERO] = 0.0;
        for (s, &g) in refs.iter_mut().zip(&grads) {
            ref_adam_step(s, f64::from(g), t, &cfg);
        }
        bufs.step(&ctx, &adam, &grads, t, &cfg);
        let (p, m, v) = bufs.read(&ctx);
        for i in 0..n {
            let r = &refs[i];
            assert!(
                !r.saturated || SAT.contains(&i),
                "element {i}: unplanned v overflow"
            );
            // A device may flush denormal results to zero (NVIDIA does; docs/NVIDIA.md):
            // each step can lose less than the smallest normal in m and in v.
            let flush = 2.0 * f64::from(t) * f64::from(f32::MIN_POSITIVE);
            let tiny = f64::from(f32::MIN_POSITIVE);
            let em = ((f64::from(m[i]) - r.m).abs() - flush).max(0.0) / r.m_abs.max(tiny);
            let ev = ((f64::from(v[i]) - r.v).abs() - flush).max(0.0) / r.v.max(tiny);
            let ep = (f64::from(p[i]) - r.p).abs() / (r.p.abs() + t as f64 * f64::from(cfg.lr));
            assert!(
                em <= ADAM_TOL && ev <= ADAM_TOL && ep <= ADAM_TOL,
                "step {t} element {i}: g {} p {} (ref {}) m {} (ref {}) v {} (ref {}): \
                 errors {em:e} {ev:e} {ep:e}",
                grads[i],
                p[i],
                r.p,
                m[i],
                r.m,
                v[i],
                r.v
            );
            worst = (worst.0.max(em), worst.1.max(ev), worst.2.max(ep));
        }
        for &i in &SAT {
            assert!(p[i].is_finite() && m[i].is_finite() && v[i].is_finite());
            assert_eq!(refs[i].saturated, t >= 4);
            if t >= 4 {
                assert_eq!(v[i], f32::MAX, "v saturates instead of overflowing");
            }
        }
        assert_eq!(
            p[ZERO].to_bits(),
            p0[ZERO].to_bits(),
            "zero gradient moved p"
        );
        assert_eq!((m[ZERO], v[ZERO]), (0.0, 0.0));
    }
    assert!(
        !adam.read_nonfinite().unwrap(),
        "no non-finite value was involved"
    );
    println!(
        "adam: max rel error m {:.3e}, v {:.3e}, p {:.3e} (bound {ADAM_TOL:e})",
        worst.0, worst.1, worst.2
    );
    finish(&ctx);
}

/// Selective Adam (`skip_zero`): elements whose gradient is exactly zero keep p, m and
/// v bit for bit (dense Adam decays their moments and moves p by the momentum); the
/// others take the dense step (the f64 reference).
#[test]
fn selective_adam_leaves_zero_gradient_elements_untouched() {
    let ctx = context();
    let adam = Adam::new(&ctx).unwrap();
    let cfg = AdamConfig {
        skip_zero: true,
        ..AdamConfig::default()
    };
    let mut rng = Rng(0x5e1);
    let n = 20_011usize;
    let p0: Vec<f32> = (0..n).map(|_| rng.range(-3.0, 3.0) as f32).collect();
    let bufs = AdamBufs::new(&ctx, &p0, &vec![0.0; n], &vec![0.0; n]);
    let mut refs: Vec<RefAdam> = p0
        .iter()
        .map(|&p| RefAdam {
            p: f64::from(p),
            ..Default::default()
        })
        .collect();
    let (mut skipped, mut stepped, mut moving) = (0, 0, 0);
    for t in 1..=6u32 {
        // Each step a different third of the elements has no gradient (a voxel no
        // pixel of the view reached); after step 1 they carry non-zero moments.
        let grads: Vec<f32> = (0..n)
            .map(|i| {
                if (i + t as usize).is_multiple_of(3) {
                    0.0
                } else {
                    random_grad(&mut rng)
                }
            })
            .collect();
        let (p_before, m_before, v_before) = bufs.read(&ctx);
        bufs.step(&ctx, &adam, &grads, t, &cfg);
        let (p, m, v) = bufs.read(&ctx);
        for i in 0..n {
            if grads[i] == 0.0 {
                assert_eq!(
                    (p[i].to_bits(), m[i].to_bits(), v[i].to_bits()),
                    (
                        p_before[i].to_bits(),
                        m_before[i].to_bits(),
                        v_before[i].to_bits()
                    ),
                    "step {t} element {i}: a zero gradient changed the state"
                );
                if m_before[i] != 0.0 {
                    moving += 1; // dense Adam would have moved this one
                }
                skipped += 1;
            } else {
                ref_adam_step(&mut refs[i], f64::from(grads[i]), t, &cfg);
                let r = &refs[i];
                // The reference's own bias corrections use the global step t, as the
                // kernel does, from this element's own (sparser) history of moments.
                let ep = (f64::from(p[i]) - r.p).abs() / (r.p.abs() + t as f64 * f64::from(cfg.lr));
                assert!(
                    ep <= ADAM_TOL,
                    "step {t} element {i}: g {} p {} (before {}, ref {}) m {} (ref {}) v {} (ref {})",
                    grads[i],
                    p[i],
                    p_before[i],
                    r.p,
                    m[i],
                    r.m,
                    v[i],
                    r.v
                );
                stepped += 1;
            }
        }
    }
    println!("selective adam: {skipped} skipped ({moving} with momentum), {stepped} stepped");
    assert!(
        moving > 1000,
        "the test must skip elements dense Adam would move"
    );
    finish(&ctx);
}

#[test]
fn adam_zero_gradient_is_exact_noop() {
    let ctx = context();
    let adam = Adam::new(&ctx).unwrap();
    let mut rng = Rng(7);
    let n = 4099usize;
    let p0: Vec<f32> = (0..n).map(|_| rng.range(-5.0, 5.0) as f32).collect();
    let bufs = AdamBufs::new(&ctx, &p0, &vec![0.0; n], &vec![0.0; n]);
    // Also with eps = 0 (0/0 must not happen) and a different config.
    let configs = [
        AdamConfig::default(),
        AdamConfig {
            lr: 0.5,
            beta1: 0.9,
            beta2: 0.999,
            eps: 0.0,
            skip_zero: false,
        },
    ];
    for (k, cfg) in configs.iter().enumerate() {
        for t in 1..=3 {
            bufs.step(&ctx, &adam, &vec![0.0; n], t + 3 * k as u32, cfg);
        }
    }
    let (p, m, v) = bufs.read(&ctx);
    for i in 0..n {
        assert_eq!(p[i].to_bits(), p0[i].to_bits(), "element {i}");
        assert_eq!((m[i].to_bits(), v[i].to_bits()), (0, 0), "element {i}");
    }
    assert!(!adam.read_nonfinite().unwrap());
    finish(&ctx);
}

#[test]
fn adam_flags_non_finite() {
    let ctx = context();
    let adam = Adam::new(&ctx).unwrap();
    let cfg = AdamConfig::default();
    // Not a multiple of 4: the last invocation does the remainder element by element.
    let n = 1003usize;
    let p0: Vec<f32> = (0..n).map(|i| i as f32 * 0.01 - 3.0).collect();
    let m0 = vec![0.25f32; n];
    let v0 = vec![0.5f32; n];
    let bufs = AdamBufs::new(&ctx, &p0, &m0, &v0);
    assert!(!adam.read_nonfinite().unwrap(), "flag starts clear");

    let finite: Vec<f32> = (0..n).map(|i| (i as f32 - 500.0) * 0.1).collect();
    for (i, bad) in [
        (17usize, f32::NAN),
        (900, f32::INFINITY),
        (3, f32::NEG_INFINITY),
        (1001, f32::NAN),
    ] {
        let mut g = finite.clone();
        g[i] = bad;
        bufs.step(&ctx, &adam, &g, 1, &cfg);
        assert!(
            adam.read_nonfinite().unwrap(),
            "{bad} gradient at {i} not flagged"
        );
        let (p, m, v) = bufs.read(&ctx);
        // The offending element keeps its state (no NaN spreads into it).
        assert!(p[i].is_finite() && m[i].is_finite() && v[i].is_finite());
        ctx.submit_and_wait(|cmd| {
            adam.record_reset(cmd);
            Ok(())
        })
        .unwrap();
        assert!(!adam.read_nonfinite().unwrap(), "reset clears the flag");
    }
    let (p_before, _, _) = bufs.read(&ctx);
    assert!(p_before[17].to_bits() != p0[17].to_bits() || finite[17] == 0.0);

    // Finite everything: no flag.
    bufs.step(&ctx, &adam, &finite, 2, &cfg);
    assert!(!adam.read_nonfinite().unwrap());

    // A parameter pushed past f32::MAX (huge lr): the new p is -inf, flagged.
    let mut p = p_before;
    p[5] = f32::MAX;
    ctx.upload(&bufs.p, 0, &p).unwrap();
    let big = AdamConfig { lr: 1e38, ..cfg };
    let mut g = vec![0.0f32; n];
    g[5] = -1.0; // m < 0 (earlier gradients of element 5 are negative too): p grows
    bufs.step(&ctx, &adam, &g, 3, &big);
    assert!(adam.read_nonfinite().unwrap(), "overflowing p not flagged");
    ctx.submit_and_wait(|cmd| {
        adam.record_reset(cmd);
        Ok(())
    })
    .unwrap();
    assert!(!adam.read_nonfinite().unwrap());
    finish(&ctx);
}

/// More than `maxComputeWorkGroupCount[0]` workgroups (of 256 invocations, 4 elements
/// each): the 2-D grid covers every element once and nothing past `count`.
#[test]
fn adam_two_dimensional_grid() {
    let ctx = context();
    let max_x = ctx.info().max_compute_work_group_count[0];
    if u64::from(max_x) * 1024 > 1 << 27 {
        eprintln!("skipped: maxComputeWorkGroupCount[0] = {max_x} needs no 2-D grid here");
        return;
    }
    let adam = Adam::new(&ctx).unwrap();
    let cfg = AdamConfig::default();
    let count = (max_x + 2) * 1024 + 77;
    let slack = 300u64;
    let bytes = (u64::from(count) + slack) * 4;
    let mk = |name| ctx.buffer(name, bytes, Memory::Device).unwrap();
    let (p, g, m, v) = (mk("p"), mk("g"), mk("m"), mk("v"));
    ctx.submit_and_wait(|cmd| {
        recorder::fill(&ctx, cmd, &p, 0, bytes, 1.0f32.to_bits());
        recorder::fill(&ctx, cmd, &g, 0, bytes, 0.5f32.to_bits());
        recorder::fill(&ctx, cmd, &m, 0, bytes, 0);
        recorder::fill(&ctx, cmd, &v, 0, bytes, 0);
        recorder::barrier(&ctx, cmd);
        adam.record(
            cmd,
            p.address(),
            g.address(),
            m.address(),
            v.address(),
            count,
            1,
            &cfg,
        );
        Ok(())
    })
    .unwrap();
    let pv: Vec<f32> = ctx.download_all(&p).unwrap();
    let mv: Vec<f32> = ctx.download_all(&m).unwrap();
    let n = count as usize;
    // Step 1 from zero state moves by lr·sign(g) (up to rounding).
    assert!((f64::from(pv[0]) - (1.0 - f64::from(cfg.lr))).abs() < 1e-6);
    assert!(
        pv[..n].iter().all(|&x| x == pv[0]),
        "every element updated alike"
    );
    assert!(mv[..n].iter().all(|&x| x == mv[0]) && mv[0] != 0.0);
    assert!(pv[n..].iter().all(|&x| x == 1.0), "nothing past count");
    assert!(mv[n..].iter().all(|&x| x == 0.0), "nothing past count");
    finish(&ctx);
}

#[test]
fn tv_matches_f64_reference() {
    let ctx = context();
    let mut rng = Rng(0x7f);
    for mut tv in tv_variants(&ctx) {
        for form in [TvForm::L2, TvForm::L1] {
            tv.set_form(form);
            let mut worst = (0.0f64, 0.0f64);
            // Partial last workgroup (41³ = 68 921), a tiny one, and heavy sharing.
            let layouts = [
                dense_layout(&mut rng, 41, 123),
                dense_layout(&mut rng, 2, 5),
                pool_layout(&mut rng, 30_000, 2000),
                pool_layout(&mut rng, 5_000, 16),
                pool_layout(&mut rng, 20_000, 2), // extreme contention: 2 words
            ];
            for (li, layout) in layouts.iter().enumerate() {
                for weight in [1.0f32, 0.37, -2.5] {
                    // Every third case has many exactly equal neighbours (values in
                    // {−1, 0, 1}): L1's tie rule (−1 to both ends) is exercised.
                    let geo = if weight == 0.37 {
                        (0..layout.points)
                            .map(|_| rng.below(3) as f32 - 1.0)
                            .collect()
                    } else {
                        random_geo(&mut rng, layout.points)
                    };
                    let e = check_tv(&ctx, &mut tv, layout, &geo, weight, &mut rng);
                    worst = (worst.0.max(e.value), worst.1.max(e.grad));
                    println!(
                        "tv ({:?}, {form:?}): layout {li} weight {weight}: rel error value {:.3e}, grad {:.3e} of the bound",
                        tv.reduction(),
                        e.value,
                        e.grad
                    );
                }
            }
            println!(
                "tv ({:?}, {form:?}): max rel error value {:.3e}, grad {:.3e} of the bound",
                tv.reduction(),
                worst.0,
                worst.1
            );
        }
    }
    finish(&ctx);
}

#[test]
fn tv_weight_zero_and_empty() {
    let ctx = context();
    let mut rng = Rng(3);
    for mut tv in tv_variants(&ctx) {
        let layout = dense_layout(&mut rng, 9, 0);
        let geo = random_geo(&mut rng, layout.points);
        // Weight 0: value computed, gradient untouched (checked in check_tv).
        check_tv(&ctx, &mut tv, &layout, &geo, 0.0, &mut rng);
        // No voxels: nothing dispatched, value 0.
        let g = ctx.buffer_from("g", &[1.5f32; 10]).unwrap();
        let c = ctx.buffer_from("c", &[0u32; 8]).unwrap();
        let geo_b = ctx.buffer_from("geo", &[1.0f32; 10]).unwrap();
        ctx.submit_and_wait(|cmd| {
            tv.record(cmd, c.address(), geo_b.address(), g.address(), 0, 1.0)
        })
        .unwrap();
        assert_eq!(tv.read_value().unwrap(), 0.0);
        assert_eq!(ctx.download_all::<f32>(&g).unwrap(), vec![1.5f32; 10]);
    }
    finish(&ctx);
}

/// Two records in one command buffer, the second growing the partials buffer: both
/// gradients are added, the value is the second's.
#[test]
fn tv_accumulates_and_grows() {
    let ctx = context();
    let mut rng = Rng(11);
    // Grid-point gradients (the ordered variant writes per voxel corner: check_tv), each
    // variant with both forms in turn.
    for (vi, mut tv) in tv_variants(&ctx)
        .into_iter()
        .filter(|t| t.reduction() != Reduction::Ordered)
        .enumerate()
    {
        tv.set_form([TvForm::L2, TvForm::L1][vi % 2]);
        let small = dense_layout(&mut rng, 3, 0);
        let big = dense_layout(&mut rng, 30, 0);
        let points = big.points;
        assert!(small.points <= points);
        let geo = random_geo(&mut rng, points);
        let geo64: Vec<f64> = geo.iter().map(|&g| f64::from(g)).collect();
        let cs = ctx.buffer_from("cs", &small.corners).unwrap();
        let cb = ctx.buffer_from("cb", &big.corners).unwrap();
        let geo_b = ctx.buffer_from("geo", &geo).unwrap();
        let grad_b = ctx.buffer_from("grad", &vec![0.0f32; points]).unwrap();
        let (ws, wb) = (0.5f32, 2.0f32);
        ctx.submit_and_wait(|cmd| {
            tv.record(cmd, cs.address(), geo_b.address(), grad_b.address(), 27, ws)?;
            tv.record(
                cmd,
                cb.address(),
                geo_b.address(),
                grad_b.address(),
                27_000,
                wb,
            )
        })
        .unwrap();
        let l_ref = ref_tv_value(tv.form(), &big.corners, &geo64);
        let value = tv.read_value().unwrap();
        assert!(
            (value - l_ref).abs() <= TV_VALUE_TOL * l_ref,
            "{value} vs {l_ref}"
        );
        let (gs, ss, as_) = ref_tv_grad(tv.form(), &small.corners, &geo64);
        let (gb, sb, ab) = ref_tv_grad(tv.form(), &big.corners, &geo64);
        let grad: Vec<f32> = ctx.download_all(&grad_b).unwrap();
        for i in 0..points {
            let expect = f64::from(ws) * gs[i] + f64::from(wb) * gb[i];
            let scale = f64::from(ws) * ss[i] + f64::from(wb) * sb[i];
            assert!(
                (f64::from(grad[i]) - expect).abs() <= grad_units(as_[i] + ab[i]) * scale,
                "point {i}: {} vs {expect}",
                grad[i]
            );
        }
        assert_eq!(tv.read_lost().unwrap(), 0);
    }
    finish(&ctx);
}

/// The reference gradient against central differences of the reference value. L2: L is
/// quadratic in geo, so central differences are exact up to the rounding of L: |fd −
/// grad| ≤ 1e-9·max(|grad|, 1) + 16·ε₆₄·L/h. L1: L is piecewise linear, so the same
/// holds at points none of whose edges changes sign within ±h (others are skipped,
/// and at least 90 % must be checked); SVRaster's tie rule is a choice at the kinks,
/// checked on exact ties by the GPU test.
#[test]
fn tv_reference_gradient_matches_finite_differences() {
    let mut rng = Rng(5);
    for form in [TvForm::L2, TvForm::L1] {
        // Pool layouts repeat points within a voxel: an edge from a point to itself has
        // no finite difference, but gets L1's tie rule; L1 uses dense layouts only.
        let layouts = match form {
            TvForm::L2 => [dense_layout(&mut rng, 3, 2), pool_layout(&mut rng, 40, 30)],
            TvForm::L1 => [dense_layout(&mut rng, 3, 2), dense_layout(&mut rng, 5, 7)],
        };
        for layout in layouts {
            let geo: Vec<f64> = random_geo(&mut rng, layout.points)
                .iter()
                .map(|&g| f64::from(g))
                .collect();
            let (grad, _, _) = ref_tv_grad(form, &layout.corners, &geo);
            let l = ref_tv_value(form, &layout.corners, &geo);
            let (mut worst, mut checked) = (0.0f64, 0usize);
            for i in 0..layout.points {
                let h = 1e-3 * geo[i].abs().max(1.0);
                // The closest neighbour of point i along any edge.
                let near = layout
                    .corners
                    .chunks_exact(8)
                    .flat_map(|c8| {
                        (0..8)
                            .filter(move |&a| c8[a] as usize == i)
                            .flat_map(move |a| [4, 2, 1].map(|k| c8[a ^ k] as usize))
                    })
                    .map(|j| (geo[i] - geo[j]).abs())
                    .fold(f64::INFINITY, f64::min);
                if form == TvForm::L1 && near <= 2.0 * h {
                    continue;
                }
                let mut gp = geo.clone();
                gp[i] += h;
                let mut gm = geo.clone();
                gm[i] -= h;
                let fd = (ref_tv_value(form, &layout.corners, &gp)
                    - ref_tv_value(form, &layout.corners, &gm))
                    / (gp[i] - gm[i]);
                let tol = 1e-9 * grad[i].abs().max(1.0) + 16.0 * f64::EPSILON * l / h;
                let e = (fd - grad[i]).abs() / tol;
                assert!(
                    e <= 1.0,
                    "{form:?} point {i}: fd {fd} vs analytic {}",
                    grad[i]
                );
                worst = worst.max(e);
                checked += 1;
            }
            assert!(
                checked * 10 >= layout.points * 9,
                "{form:?}: only {checked} of {} points away from kinks",
                layout.points
            );
            println!(
                "tv {form:?} reference vs central differences: max error / tolerance {worst:.3e} ({checked} points)"
            );
        }
    }
}
