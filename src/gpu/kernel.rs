//! Compute kernels: one pipeline per GLSL file. Kernels take their data through a
//! push-constant block holding buffer device addresses and scalars; the Rust mirror of
//! that block is checked against the size reflected from the SPIR-V at compile time
//! (see [`push_constants!`](crate::push_constants)).

use std::collections::HashMap;
use std::sync::Arc;

use ash::vk;

use super::context::{Context, Inner};
use crate::error::{Error, Result, VkContext};

/// A compiled kernel as emitted by `build.rs` (see `gpu::kernels`).
#[derive(Debug)]
pub struct KernelSource {
    /// Path below `glsl/` without extension, e.g. `sort/onesweep`.
    pub name: &'static str,
    /// SPIR-V bytes.
    pub spirv: &'static [u8],
    /// `local_size_{x,y,z}` of the shader.
    pub local_size: [u32; 3],
    /// Bytes of the push-constant block (0 if none).
    pub push_size: u32,
    /// Bytes of its `shared` variables (reflected by build.rs from the SPIR-V).
    pub shared_size: u32,
}

/// The pipelines of a family of variants (`kernels::<FAMILY>_VARIANTS`, two axes), in
/// the same order.
pub fn kernel_grid<const A: usize, const B: usize>(
    ctx: &Context,
    sources: &[[&'static KernelSource; B]; A],
) -> Result<[[Kernel; B]; A]> {
    let mut rows = Vec::with_capacity(A);
    for row in sources {
        let mut ks = Vec::with_capacity(B);
        for s in row {
            ks.push(Kernel::new(ctx, s)?);
        }
        rows.push(
            <[Kernel; B]>::try_from(ks).unwrap_or_else(|_| unreachable!("B kernels per row")),
        );
    }
    Ok(<[[Kernel; B]; A]>::try_from(rows).unwrap_or_else(|_| unreachable!("A rows")))
}

/// The pipelines a context has made, by kernel (see `Inner::pipelines`).
#[derive(Default)]
pub(crate) struct PipelineRegistry {
    made: HashMap<(&'static str, usize), (vk::Pipeline, vk::PipelineLayout)>,
}

impl PipelineRegistry {
    pub(crate) fn len(&self) -> usize {
        self.made.len()
    }

    /// Destroys every pipeline and layout (the context is dropping: no kernel is left).
    pub(crate) fn destroy(&mut self, dev: &ash::Device) {
        for (_, (pipeline, layout)) in self.made.drain() {
            unsafe {
                dev.destroy_pipeline(pipeline, None);
                dev.destroy_pipeline_layout(layout, None);
            }
        }
    }
}

/// Makes and names `source`'s pipeline and layout on `ctx`.
fn make_pipeline(
    ctx: &Context,
    source: &'static KernelSource,
) -> Result<(vk::Pipeline, vk::PipelineLayout)> {
    let dev = ctx.device();
    let limit = ctx.info().max_compute_shared_memory_size;
    if source.shared_size > limit {
        return Err(Error::Gpu(format!(
            "kernel {} declares {} bytes of shared memory; {} allows {} \
             (the caller should have chosen a smaller variant)",
            source.name,
            source.shared_size,
            ctx.info().name,
            limit
        )));
    }
    let code = ash::util::read_spv(&mut std::io::Cursor::new(source.spirv))
        .map_err(|e| Error::Gpu(format!("kernel {}: bad SPIR-V: {e}", source.name)))?;
    let module = unsafe {
        dev.create_shader_module(&vk::ShaderModuleCreateInfo::default().code(&code), None)
    }
    .vk("vkCreateShaderModule")?;
    let ranges = [vk::PushConstantRange {
        stage_flags: vk::ShaderStageFlags::COMPUTE,
        offset: 0,
        size: source.push_size,
    }];
    let lci = if source.push_size > 0 {
        vk::PipelineLayoutCreateInfo::default().push_constant_ranges(&ranges)
    } else {
        vk::PipelineLayoutCreateInfo::default()
    };
    let layout = match unsafe { dev.create_pipeline_layout(&lci, None) } {
        Ok(l) => l,
        Err(e) => {
            unsafe { dev.destroy_shader_module(module, None) };
            return Err(Error::Vulkan {
                call: "vkCreatePipelineLayout",
                result: e,
            });
        }
    };
    let full = ctx.info().full_subgroups
        && source.local_size[0] * source.local_size[1] * source.local_size[2] >= 128;
    let flags = if full {
        vk::PipelineShaderStageCreateFlags::REQUIRE_FULL_SUBGROUPS
    } else {
        vk::PipelineShaderStageCreateFlags::empty()
    };
    let stage = vk::PipelineShaderStageCreateInfo::default()
        .stage(vk::ShaderStageFlags::COMPUTE)
        .flags(flags)
        .module(module)
        .name(c"main");
    let ci = [vk::ComputePipelineCreateInfo::default()
        .stage(stage)
        .layout(layout)];
    let res = unsafe { dev.create_compute_pipelines(ctx.inner.pipeline_cache, &ci, None) };
    unsafe { dev.destroy_shader_module(module, None) };
    let pipeline = match res {
        Ok(p) => p[0],
        Err((_, e)) => {
            unsafe { dev.destroy_pipeline_layout(layout, None) };
            return Err(Error::Vulkan {
                call: "vkCreateComputePipelines",
                result: e,
            });
        }
    };
    ctx.set_name(pipeline, source.name);
    Ok((pipeline, layout))
}

/// A compute pipeline and its layout: a handle to the context's pipeline for the
/// kernel, made on the context's first use of it (so making a renderer, backward or
/// sort again on a context costs no shader compilation).
pub struct Kernel {
    inner: Arc<Inner>,
    pub(crate) source: &'static KernelSource,
    pipeline: vk::Pipeline,
    layout: vk::PipelineLayout,
    /// The device's largest workgroup count along x (1-D work beyond it goes 2-D).
    max_groups_x: u32,
}

impl Kernel {
    /// The kernel's pipeline on `ctx`: made on the first call for `source` on this
    /// context, taken from the context's registry afterwards (keyed by the kernel's
    /// name and SPIR-V).
    pub fn new(ctx: &Context, source: &'static KernelSource) -> Result<Self> {
        let key = (source.name, source.spirv.as_ptr() as usize);
        let mut reg = ctx
            .inner
            .pipelines
            .lock()
            .map_err(|_| Error::Gpu("the pipeline registry's lock is poisoned".into()))?;
        let (pipeline, layout) = match reg.made.get(&key) {
            Some(&made) => made,
            None => {
                let made = make_pipeline(ctx, source)?;
                reg.made.insert(key, made);
                made
            }
        };
        drop(reg);
        Ok(Kernel {
            inner: ctx.inner.clone(),
            source,
            pipeline,
            layout,
            max_groups_x: ctx.info().max_compute_work_group_count[0],
        })
    }

    pub fn name(&self) -> &'static str {
        self.source.name
    }
    pub fn local_size(&self) -> [u32; 3] {
        self.source.local_size
    }

    fn bind<P: bytemuck::Pod>(&self, cmd: vk::CommandBuffer, push: &P) {
        debug_assert_eq!(std::mem::size_of::<P>(), self.source.push_size as usize);
        let dev = &self.inner.device;
        unsafe {
            dev.cmd_bind_pipeline(cmd, vk::PipelineBindPoint::COMPUTE, self.pipeline);
            if self.source.push_size > 0 {
                dev.cmd_push_constants(
                    cmd,
                    self.layout,
                    vk::ShaderStageFlags::COMPUTE,
                    0,
                    bytemuck::bytes_of(push),
                );
            }
        }
    }

    /// Records a dispatch of `groups` workgroups.
    pub fn dispatch<P: bytemuck::Pod>(&self, cmd: vk::CommandBuffer, push: &P, groups: [u32; 3]) {
        if groups.contains(&0) {
            return;
        }
        self.bind(cmd, push);
        unsafe {
            self.inner
                .device
                .cmd_dispatch(cmd, groups[0], groups[1], groups[2])
        };
    }

    /// Workgroups that cover `items` threads of 1-D work (the reflected `local_size_x`
    /// threads each).
    pub fn groups_1d(&self, items: u32) -> u32 {
        items.div_ceil(self.source.local_size[0])
    }

    /// Records a dispatch covering `items` threads of 1-D work: [`Self::groups_1d`]
    /// workgroups, as a 2-D grid where they exceed the device's x limit (the shader
    /// derives its linear index from `linear_group_id` in common.glsl).
    pub fn dispatch_1d<P: bytemuck::Pod>(&self, cmd: vk::CommandBuffer, push: &P, items: u32) {
        let groups = super::grid_2d(self.groups_1d(items), self.max_groups_x);
        self.dispatch(cmd, push, groups);
    }

    /// Records an indirect dispatch reading `VkDispatchIndirectCommand` at `offset`.
    pub fn dispatch_indirect<P: bytemuck::Pod>(
        &self,
        cmd: vk::CommandBuffer,
        push: &P,
        args: vk::Buffer,
        offset: u64,
    ) {
        self.bind(cmd, push);
        unsafe { self.inner.device.cmd_dispatch_indirect(cmd, args, offset) };
    }
}

/// A kernel made on first use: for variants that many runs never dispatch (each
/// pipeline costs a JIT compilation on CPU devices).
pub struct LazyKernel {
    source: &'static KernelSource,
    cell: std::sync::OnceLock<Kernel>,
}

impl LazyKernel {
    pub fn new(source: &'static KernelSource) -> Self {
        LazyKernel {
            source,
            cell: std::sync::OnceLock::new(),
        }
    }

    /// The kernel, made now if this is its first use.
    pub fn get(&self, ctx: &Context) -> Result<&Kernel> {
        if let Some(k) = self.cell.get() {
            return Ok(k);
        }
        let made = Kernel::new(ctx, self.source)?;
        // Another thread may have made it meanwhile: keep the first, drop ours.
        let _ = self.cell.set(made);
        Ok(self.cell.get().expect("set above"))
    }
}

#[cfg(test)]
mod tests {
    use super::KernelSource;

    /// Every kernel with push constants has its Rust mirror checked by
    /// `push_constants!(KERNEL, Mirror)` or `push_constants!(FAMILY_VARIANTS, Mirror)`
    /// somewhere in src/ (build.rs generates the
    /// checks; this makes sure none is left out when a kernel or variant is added).
    #[test]
    fn every_push_block_has_a_checked_mirror() {
        fn walk(dir: &std::path::Path, text: &mut String) {
            for e in std::fs::read_dir(dir).unwrap() {
                let p = e.unwrap().path();
                if p.is_dir() {
                    walk(&p, text);
                } else if p.extension().is_some_and(|x| x == "rs") {
                    text.push_str(&std::fs::read_to_string(&p).unwrap());
                }
            }
        }
        let mut src = String::new();
        walk(
            &std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("src"),
            &mut src,
        );
        let checked = |k: &KernelSource| {
            let ident = k.name.replace(['/', '-', '.'], "_").to_uppercase();
            src.contains(&format!("push_constants!({ident},"))
                || crate::gpu::kernels::FAMILIES
                    .iter()
                    .any(|(family, members)| {
                        src.contains(&format!("push_constants!({family},"))
                            && members.iter().any(|m| m.name == k.name)
                    })
        };
        let missing: Vec<&str> = crate::gpu::kernels::ALL
            .iter()
            .filter(|k| k.push_size > 0 && !checked(k))
            .map(|k| k.name)
            .collect();
        assert!(
            missing.is_empty(),
            "kernels whose push constants no Rust mirror is checked against: {missing:?}"
        );
    }
}
