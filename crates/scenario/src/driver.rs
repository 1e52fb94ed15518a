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
//! * on Ctrl-C ([`crate::context::INTERRUPTED`]) or at [`RunContext::stop_at_step`]: a final frame (if
//!   none was due), a checkpoint, and [`RunError::Interrupted`];
//! * at the end: a checkpoint marked finished.

use crate::context::{RunContext, RunError};
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
        if crate::context::INTERRUPTED.load(Ordering::Relaxed) || ctx.stop_at_step == Some(step) {
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

#[cfg(test)]
mod tests {
    use super::*;

    /// A schedule of `end` steps with a frame every `frame_every` steps; records what the
    /// driver asks of it.
    #[derive(Default)]
    struct Log {
        step: u64,
        end: u64,
        frame_every: u64,
        frames: Vec<u64>,
        checkpoints: Vec<u64>,
        boundaries: Vec<u64>,
        flushes: usize,
    }

    impl Stepper for Log {
        fn step_count(&self) -> u64 {
            self.step
        }
        fn max_steps(&self) -> u64 {
            self.end
        }
        fn time(&self) -> f64 {
            self.step as f64 * 0.01
        }
        fn finished(&self) -> bool {
            self.step >= self.end
        }
        fn advance(&mut self) -> Result<(), RunError> {
            self.step += 1;
            Ok(())
        }
        fn frame_due(&self) -> bool {
            self.step.is_multiple_of(self.frame_every)
        }
        fn write_frame(&mut self) -> Result<(), RunError> {
            self.frames.push(self.step);
            Ok(())
        }
        fn flush(&mut self) -> Result<(), RunError> {
            self.flushes += 1;
            Ok(())
        }
        fn save_checkpoint(&mut self, _ctx: &RunContext) -> Result<(), RunError> {
            self.checkpoints.push(self.step);
            Ok(())
        }
        fn at_boundary(&mut self) -> Result<(), RunError> {
            self.boundaries.push(self.step);
            Ok(())
        }
    }

    fn ctx(stop_at: Option<u64>) -> RunContext {
        RunContext {
            stop_at_step: stop_at,
            ..RunContext::new(std::env::temp_dir(), 1, false)
        }
    }

    fn log(step: u64) -> Log {
        Log {
            step,
            end: 25,
            frame_every: 10,
            ..Log::default()
        }
    }

    #[test]
    fn a_full_run_writes_each_due_frame_and_checkpoint_once_and_a_final_checkpoint() {
        let mut s = log(0);
        drive(&mut s, &ctx(None), false, 8).unwrap();
        assert_eq!(s.step, 25);
        assert_eq!(s.frames, [0, 10, 20]);
        // every 8 steps after the start, and the final one (25 is not a multiple of 8)
        assert_eq!(s.checkpoints, [8, 16, 24, 25]);
        assert_eq!(s.boundaries, (0..=25).collect::<Vec<_>>());
        assert_eq!(s.flushes, 0);
    }

    #[test]
    fn an_interrupt_writes_an_off_schedule_frame_and_a_checkpoint_and_says_where() {
        let mut s = log(0);
        let e = drive(&mut s, &ctx(Some(13)), false, 8).unwrap_err();
        assert!(matches!(e, RunError::Interrupted { step: 13, .. }), "{e}");
        assert_eq!(s.frames, [0, 10, 13]);
        assert_eq!(s.checkpoints, [8, 13]);
        assert_eq!(s.flushes, 1);
        // at a frame step the frame is not written twice
        let mut s = log(0);
        drive(&mut s, &ctx(Some(20)), false, 8).unwrap_err();
        assert_eq!(s.frames, [0, 10, 20]);
    }

    #[test]
    fn a_resumed_run_repeats_neither_the_frame_nor_the_checkpoint_of_its_start() {
        // from the checkpoint of step 16 (no frame there) and of step 20 (a frame step)
        for start in [16, 20] {
            let mut s = log(start);
            drive(&mut s, &ctx(None), true, 8).unwrap();
            let frames: Vec<u64> = [10, 20].into_iter().filter(|&f| f > start).collect();
            assert_eq!(s.frames, frames, "resumed at {start}");
            let checkpoints: Vec<u64> = [24, 25].into_iter().filter(|&c| c > start).collect();
            assert_eq!(s.checkpoints, checkpoints, "resumed at {start}");
            // the boundary work of the start is repeated (it must be idempotent)
            assert_eq!(s.boundaries.first(), Some(&start));
        }
        // together, an interrupted run and its resume write each frame once
        let mut a = log(0);
        drive(&mut a, &ctx(Some(20)), false, 8).unwrap_err();
        let mut b = log(20);
        drive(&mut b, &ctx(None), true, 8).unwrap();
        let all: Vec<u64> = a.frames.iter().chain(&b.frames).copied().collect();
        assert_eq!(all, [0, 10, 20]);
    }

    #[test]
    fn no_periodic_checkpoints_when_the_interval_is_zero() {
        let mut s = log(0);
        drive(&mut s, &ctx(None), false, 0).unwrap();
        assert_eq!(s.checkpoints, [25]);
    }
}
