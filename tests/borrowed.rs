//! Embedding: a host engine creates its own ash instance/device (with validation and its
//! own debug messenger, tests/common/host.rs), lends them to the engine, and records the
//! sort into a command buffer it owns and submits itself.

use crate::common;

use common::host::{assert_host_clean, Host};
use svraster::sort::{Count, RadixSort, SortScratch};

#[test]
fn sort_on_a_borrowed_device_in_a_host_command_buffer() {
    let host = Host::new(false);
    {
        let ctx = host.context();
        assert!(!ctx.is_owned());

        let n = 200_000u32;
        let sort = RadixSort::new(&ctx, n).unwrap();
        let bufs = SortScratch::new(&ctx, n).unwrap();
        let mut rng = common::Rng(99);
        let keys: Vec<u64> = (0..n).map(|_| rng.next_u64()).collect();
        let vals: Vec<u32> = (0..n).collect();
        ctx.upload(&bufs.keys, 0, &keys).unwrap();
        ctx.upload(&bufs.values, 0, &vals).unwrap();

        // The host's own command buffer, fence and submission.
        let cmd = host.command_buffers(1)[0];
        let fence = host.fence(false);
        let mut which = None;
        host.submit(cmd, fence, |cmd| {
            which = Some(
                sort.record(cmd, &bufs.as_buffers(), Count::Host(n), 0..48, None)
                    .unwrap(),
            );
        });
        host.wait(fence);

        let (k, v) = bufs.result(which.unwrap());
        let (rk, rv) = common::reference_sort(&keys, &vals, 0, 48);
        assert_eq!(ctx.download::<u64>(k, 0, n as usize).unwrap(), rk);
        assert_eq!(ctx.download::<u32>(v, 0, n as usize).unwrap(), rv);
        assert_eq!(sort.take_errors().unwrap(), 0);
        unsafe { host.device.destroy_fence(fence, None) };
        // The engine's objects drop here; the host's device must survive that (Host's
        // drop waits for it to be idle and fails otherwise).
    }
    let log = host.log();
    drop(host);
    assert_host_clean(&log);
}
