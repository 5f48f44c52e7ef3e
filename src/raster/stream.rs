//! Frames queued behind each other ([`Renderer::render_each`]): the host records and
//! submits frame i+1, then waits for frame i (the device is busy with i+1 meanwhile)
//! and reads its image from host-visible memory. One submission per frame and no
//! queue drain in the steady state, against one submission, one drain and a download
//! per frame for [`Renderer::render`].

use super::readback::image_from_channels;
use super::{FrameCheck, FrameStats, Image, RenderOptions, Renderer, CHANNELS};
use crate::camera::Camera;
use crate::error::Error;
use crate::gpu::{recorder, Ticket, Timestamps};
use crate::scene::SceneGpu;

/// Per-stage GPU durations of one frame, in recording order (milliseconds), as
/// [`Timestamps::stages`] gives them.
pub type StageTimes = Vec<(String, f64)>;

/// A frame submitted and not yet read.
struct Queued {
    index: usize,
    ticket: Ticket,
    check: FrameCheck,
    slot: usize,
    /// Its stats, read early when the frame before it had to be rendered again (which
    /// reuses the check slots).
    stats: Option<FrameStats>,
}

impl Renderer {
    /// Renders `cams` in order and hands each frame's image and stats to `each` (in
    /// order), queueing every frame behind the next (see the module docs). A frame
    /// that comes out incomplete is grown for and rendered again, waited for; the
    /// frame queued behind it does not depend on it and stays queued.
    ///
    /// `each` may fail with its own error type (anything an engine error converts
    /// into); the first failure stops the loop.
    pub fn render_each<E: From<Error>>(
        &mut self,
        scene: &SceneGpu,
        cams: &[Camera],
        opts: &RenderOptions,
        mut each: impl FnMut(usize, Image, FrameStats) -> std::result::Result<(), E>,
    ) -> std::result::Result<(), E> {
        self.stream(scene, cams, opts, None, |i, img, st, _| each(i, img, st))
    }

    /// [`Renderer::render_each`] with each frame's stage times from GPU timestamps,
    /// still queued: frame i writes into `pools[i % 2]`, which the host reads after
    /// waiting for frame i and before recording frame i + 2 into it, so timing adds no
    /// wait (one submission per frame, one drain in all, as untimed). A frame that came
    /// out incomplete hands over the times of its redo (rendered again, waited for).
    /// Each pool needs room for a frame's marks (32 is plenty).
    pub fn render_each_timed<E: From<Error>>(
        &mut self,
        scene: &SceneGpu,
        cams: &[Camera],
        opts: &RenderOptions,
        pools: &mut [Timestamps; 2],
        mut each: impl FnMut(usize, Image, FrameStats, StageTimes) -> std::result::Result<(), E>,
    ) -> std::result::Result<(), E> {
        self.stream(scene, cams, opts, Some(pools), |i, img, st, times| {
            let times = times.expect("timed frames carry their stage times");
            each(i, img, st, times)
        })
    }

    fn stream<E: From<Error>>(
        &mut self,
        scene: &SceneGpu,
        cams: &[Camera],
        opts: &RenderOptions,
        mut pools: Option<&mut [Timestamps; 2]>,
        mut each: impl FnMut(usize, Image, FrameStats, Option<StageTimes>) -> std::result::Result<(), E>,
    ) -> std::result::Result<(), E> {
        let ctx = self.ctx.clone();
        let mut queued: Option<Queued> = None;
        for (i, cam) in cams.iter().enumerate() {
            self.prepare(scene, cam, opts)?;
            let plan = self.plan(scene, cam, opts)?;
            let slot = i % self.image_slots.len();
            let (w, h) = plan.output_size();
            let bytes = u64::from(w) * u64::from(h) * CHANNELS as u64 * 4;
            self.image_slots[slot].ensure(&ctx, bytes)?;
            let ts = pools.as_deref_mut().map(|p| &mut p[i % 2]);
            let (check, ticket) = ctx.submit(|cmd| {
                self.record(cmd, scene, cam, opts, ts)?;
                let check = self.record_checks(cmd, None)?;
                let src = if plan.supersampled {
                    self.out_img.get()
                } else {
                    self.img.get()
                };
                recorder::copy(&ctx, cmd, src, self.image_slots[slot].get(), 0, 0, bytes);
                Ok(check)
            })?;
            let mut next = Queued {
                index: i,
                ticket,
                check,
                slot,
                stats: None,
            };
            if let Some(prev) = queued.take() {
                let ts = pools.as_deref_mut().map(|p| &mut p[prev.index % 2]);
                self.finish(prev, Some(&mut next), scene, cams, opts, ts, &mut each)?;
            }
            queued = Some(next);
        }
        if let Some(last) = queued.take() {
            let ts = pools.map(|p| &mut p[last.index % 2]);
            self.finish(last, None, scene, cams, opts, ts, &mut each)?;
        }
        Ok(())
    }

    /// Waits for frame `q` and hands it over; renders it again if it came out
    /// incomplete (first reading the stats of `behind`, queued after it). `ts`: the
    /// pool `q` was recorded with, read once `q` is done (or given to its redo).
    #[allow(clippy::too_many_arguments)]
    fn finish<E: From<Error>>(
        &mut self,
        q: Queued,
        behind: Option<&mut Queued>,
        scene: &SceneGpu,
        cams: &[Camera],
        opts: &RenderOptions,
        mut ts: Option<&mut Timestamps>,
        each: &mut impl FnMut(
            usize,
            Image,
            FrameStats,
            Option<StageTimes>,
        ) -> std::result::Result<(), E>,
    ) -> std::result::Result<(), E> {
        self.ctx.wait(q.ticket)?;
        let stats = match q.stats {
            Some(s) => s,
            None => self.checked_stats(&q.check)?,
        };
        if stats.complete() {
            let (w, h) = q.check.plan.output_size();
            let bytes = self.image_slots[q.slot]
                .get()
                .mapped()
                .ok_or_else(|| Error::Gpu("raster.image-slot is not host-visible".into()))?;
            let n = w as usize * h as usize * CHANNELS;
            let raw: &[f32] = bytemuck::cast_slice(&bytes[..n * 4]);
            let times = ts.map(|t| t.stages()).transpose()?;
            return each(q.index, image_from_channels(raw, w, h), stats, times);
        }
        if let Some(b) = behind {
            self.ctx.wait(b.ticket)?;
            b.stats = Some(self.checked_stats(&b.check)?);
        }
        self.grown += 1;
        if !self.grow_for(&stats)? {
            return Err(
                Error::Gpu(format!("frame incomplete but nothing to grow: {stats:?}")).into(),
            );
        }
        let stats = self.render_to_device(scene, &cams[q.index], opts, ts.as_deref_mut())?;
        let times = ts.map(|t| t.stages()).transpose()?;
        each(q.index, self.read_image()?, stats, times)
    }
}
