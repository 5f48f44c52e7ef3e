use svraster::gpu::Context;

pub fn run(ctx: &Context, json: bool) -> anyhow::Result<()> {
    let i = ctx.info();
    if json {
        let mut v = serde_json::to_value(i)?;
        if let (Some(obj), Some(b)) = (v.as_object_mut(), ctx.memory_budget()) {
            obj.insert(
                "memory_budget".into(),
                serde_json::json!({
                    "heap_bytes": b.heap_bytes,
                    "budget_bytes": b.budget_bytes,
                    "usage_bytes": b.usage_bytes,
                    "available_bytes": b.available_bytes(),
                }),
            );
        }
        println!("{}", serde_json::to_string_pretty(&v)?);
        return Ok(());
    }
    let mib = |b: u64| b as f64 / (1024.0 * 1024.0);
    println!("device              {} ({})", i.name, i.device_type);
    println!("driver              {} — {}", i.driver_name, i.driver_info);
    println!("Vulkan API          {}", i.api_version);
    println!("subgroup size       {}", i.subgroup_size);
    println!(
        "loop limit          {}",
        if i.loop_limit() {
            "assumed (CPU driver before Mesa 25): long tile lists are split into dispatches"
        } else {
            "none"
        }
    );
    println!("limits we depend on");
    println!("  maxStorageBufferRange        {:.0} MiB (not binding: kernels use buffer device addresses)", mib(i.max_storage_buffer_range));
    println!(
        "  maxMemoryAllocationSize      {:.0} MiB (largest single buffer)",
        mib(i.max_memory_allocation_size)
    );
    println!(
        "  maxComputeSharedMemorySize   {} KiB",
        i.max_compute_shared_memory_size / 1024
    );
    println!(
        "  maxComputeWorkGroupCount     {:?}",
        i.max_compute_work_group_count
    );
    println!(
        "  maxComputeWorkGroupInvocations {}",
        i.max_compute_work_group_invocations
    );
    println!(
        "  maxPushConstantsSize         {} B",
        i.max_push_constants_size
    );
    println!(
        "  timestampPeriod              {} ns",
        i.timestamp_period_ns
    );
    println!(
        "  device-local heap            {:.0} MiB",
        mib(i.device_local_heap_bytes)
    );
    match ctx.memory_budget() {
        Some(b) => println!(
            "  memory budget (VK_EXT_memory_budget) {:.0} MiB, in use {:.0} MiB: {:.0} MiB available",
            mib(b.budget_bytes),
            mib(b.usage_bytes),
            mib(b.available_bytes())
        ),
        None => println!("  memory budget                no VK_EXT_memory_budget: the heap size is used"),
    }
    println!("features enabled    {}", i.features_enabled.join(", "));
    println!(
        "validation layer    {}",
        if ctx.validation_enabled() {
            "on"
        } else {
            "off"
        }
    );
    Ok(())
}
