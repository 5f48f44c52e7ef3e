mod common;
use svraster::scan::PrefixScan;
use svraster::sort::RadixSort;
#[test]
fn smoke() {
    let ctx = common::context();
    let mut rng = common::Rng(1);
    for &n in &[0usize, 1, 5, 3000, 100_000, 1 << 20] {
        let keys: Vec<u64> = (0..n).map(|_| rng.next_u64()).collect();
        let vals: Vec<u32> = (0..n as u32).collect();
        let s = RadixSort::new(&ctx, n.max(1) as u32).unwrap();
        let t = std::time::Instant::now();
        let (k, v) = s.sort(&keys, &vals, 0..64).unwrap();
        eprintln!("n={n} {:?}", t.elapsed());
        let (rk, rv) = common::reference_sort(&keys, &vals, 0, 64);
        assert!(k == rk, "keys n={n}");
        assert!(v == rv, "vals n={n}");
        let data: Vec<u32> = (0..n).map(|_| rng.below(100) as u32).collect();
        let sc = PrefixScan::new(&ctx, n.max(1) as u32).unwrap();
        let (o, tot) = sc.scan(&data).unwrap();
        let (ro, rt) = common::reference_scan(&data);
        assert!(o == ro, "scan n={n}");
        assert_eq!(tot, rt);
    }
    common::finish(&ctx);
}
