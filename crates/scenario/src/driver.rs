//! The one stepping loop of the time-stepping scenarios: frames, checkpoints, Ctrl-C and progress
//! around a scenario's own step (docs/ARCHITECTURE.md).
//!
//! A scenario kind implements [`Stepper`]: it owns its simulation and schedule (stages, sampling,
//! controllers) and says when a frame is due and how to save itself. [`drive`] does the rest the
//! same way for every kind:
//!
//! * at every step boundary (after `n` steps): the kind's own boundary work
//!   ([`Stepper::at_boundary`], e.g. a phase change), then a frame when due and a checkpoint
//!   every `checkpoint_every` steps; on resume the frame and checkpoint of the boundary the
//!   checkpoint was written at are not repeated (the boundary work is, so it must be idempotent);
//! * on Ctrl-C ([`crate::INTERRUPTED`]) or at [`RunContext::stop_at_step`]: a final frame (if
//!   none was due), a checkpoint, and [`RunError::Interrupted`];
//! * at the end: a checkpoint marked finished.

use crate::{RunContext, RunError};
use std::sync::atomic::Ordering;

/// What a time-stepping scenario supplies to [`drive`].
pub trait Stepper {
    /// Steps done.
    fn step_count(&self) -> u64;
    /// The most steps the schedule can take (for progress; stages may end earlier).
    fn max_steps(&self) -> u64;
    /// Model time now (for progress).
    fn time(&self) -> f64;
    /// Whether the schedule is complete.
    fn finished(&self) -> bool;
    /// One step, with the scenario's own sampling and control after it.
    fn advance(&mut self) -> Result<(), RunError>;
    /// Whether a frame is due at the current step.
    fn frame_due(&self) -> bool;
    /// Writes a frame of the current state.
    fn write_frame(&mut self) -> Result<(), RunError>;
    /// Flushes the trajectory (before an interrupt returns).
    fn flush(&mut self) -> Result<(), RunError>;
    /// Writes the checkpoint of the current state.
    fn save_checkpoint(&mut self, ctx: &RunContext) -> Result<(), RunError>;
    /// Work due at the current step boundary before its frame and checkpoint: phase changes
    /// that take effect at a step count (e.g. adaptation off, sampling on). Called at every
    /// boundary, the last and the one a resumed run starts from included; at the latter it
    /// repeats what the interrupted run did there, so it must be idempotent. Default: nothing.
    fn at_boundary(&mut self) -> Result<(), RunError> {
        Ok(())
    }
}

/// Runs `s` to the end of its schedule (or to an interrupt). `resumed`: the current step is the
/// one a checkpoint was written at (its frame and checkpoint are not repeated).
pub fn drive(s: &mut impl Stepper, ctx: &RunContext, resumed: bool, checkpoint_every: u64) -> Result<(), RunError> {
    let start = s.step_count();
    let total = s.max_steps().max(start);
    let mut progress = ctx.progress(total, start);
    let report_every = (total / 200).max(1);
    loop {
        s.at_boundary()?;
        let step = s.step_count();
        if step > start || !resumed {
            if s.frame_due() {
                s.write_frame()?;
            }
            if checkpoint_every > 0 && step > start && step.is_multiple_of(checkpoint_every) && !s.finished() {
                s.save_checkpoint(ctx)?;
            }
        }
        if s.finished() {
            break;
        }
        if crate::INTERRUPTED.load(Ordering::Relaxed) || ctx.stop_at_step == Some(step) {
            if !s.frame_due() {
                s.write_frame()?; // dropped again on resume when off schedule
            }
            s.flush()?;
            s.save_checkpoint(ctx)?;
            progress.finish(step, s.time());
            return Err(RunError::Interrupted {
                step,
                dir: ctx.out_dir.clone(),
            });
        }
        s.advance()?;
        if s.step_count().is_multiple_of(report_every) {
            progress.update(s.step_count(), s.time());
        }
    }
    s.save_checkpoint(ctx)?;
    progress.finish(s.step_count(), s.time());
    Ok(())
}
