//! The setpoint queue between a source and the servo.
//!
//! A lower-priority task keeps a `heapless` SPSC queue of tool-space setpoints (position with
//! its exact velocity, acceleration and jerk: [`MotionSetpoint`]) filled from
//! a [`SetpointSource`]; the servo task takes one per sample (see
//! [`ServoLoop::step`](crate::servo_loop::ServoLoop::step): an empty queue holds the last
//! setpoint and counts an underrun) and asks for a refill when fewer than [`REFILL_BELOW`] are
//! left. The built-in [`Trajectory`](crate::waypoint_moves::Trajectory) is a source; a host link's
//! streamed motion buffer would be another.
use heapless::spsc::Producer;
use kinematics_core::trajectory::MotionSetpoint;

/// Slots of the setpoint queue: 64 (63 usable), 31.5 ms of samples.
pub const QUEUE_SLOTS: usize = 64;
/// The servo task asks for a refill when fewer setpoints than this are queued.
pub const REFILL_BELOW: usize = 32;

/// Where setpoints come from: one tool-space setpoint per servo sample, with its derivatives
/// (a source that only has positions says so with zero derivatives: the servo then feeds no
/// inertia forward and its PID does that work).
pub trait SetpointSource {
    /// The setpoint for the next sample, or `None` when the source has none now (a streamed
    /// buffer that ran dry). The servo loop holds the last setpoint if the machine is at rest
    /// when the queue runs empty, and makes a controlled stop if it is moving.
    fn next_setpoint(&mut self) -> Option<MotionSetpoint<f32>>;
}

/// Fills the queue from `source` until it is full or the source has nothing more.
pub fn refill(queue: &mut Producer<'_, MotionSetpoint<f32>>, source: &mut impl SetpointSource) {
    while queue.ready() {
        let Some(p) = source.next_setpoint() else {
            return;
        };
        let _ = queue.enqueue(p);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use heapless::spsc::Queue;

    /// Counts up; runs dry after `dry_after` setpoints.
    struct Counter(f32, f32);
    impl SetpointSource for Counter {
        fn next_setpoint(&mut self) -> Option<MotionSetpoint<f32>> {
            (self.0 < self.1).then(|| {
                self.0 += 1.0;
                MotionSetpoint {
                    velocity_mm_s: [self.0, 0.0],
                    ..MotionSetpoint::at_rest([self.0, -self.0])
                }
            })
        }
    }

    #[test]
    fn refill_fills_the_queue_in_order_and_takes_no_more_than_fits() {
        let mut q: Queue<MotionSetpoint<f32>, QUEUE_SLOTS> = Queue::new();
        let (mut tx, mut rx) = q.split();
        let mut source = Counter(0.0, f32::INFINITY);
        refill(&mut tx, &mut source);
        assert_eq!(rx.len(), QUEUE_SLOTS - 1);
        assert_eq!(
            source.0,
            (QUEUE_SLOTS - 1) as f32,
            "no setpoint drawn and dropped"
        );
        let first = rx.dequeue();
        assert_eq!(first.map(|s| s.position_mm), Some([1.0, -1.0]));
        assert_eq!(
            first.map(|s| s.velocity_mm_s),
            Some([1.0, 0.0]),
            "the derivatives travel with the position"
        );
        refill(&mut tx, &mut source);
        assert_eq!(rx.len(), QUEUE_SLOTS - 1);
        assert_eq!(rx.dequeue().map(|s| s.position_mm), Some([2.0, -2.0]));
    }

    #[test]
    fn refill_stops_when_the_source_runs_dry() {
        let mut q: Queue<MotionSetpoint<f32>, QUEUE_SLOTS> = Queue::new();
        let (mut tx, mut rx) = q.split();
        let mut source = Counter(0.0, 5.0);
        refill(&mut tx, &mut source);
        assert_eq!(rx.len(), 5);
        assert_eq!(rx.dequeue().map(|s| s.position_mm), Some([1.0, -1.0]));
        source.1 = 6.0;
        refill(&mut tx, &mut source);
        assert_eq!(rx.len(), 5);
        refill(&mut tx, &mut source);
        assert_eq!(rx.len(), 5);
        source.1 = 8.0;
        refill(&mut tx, &mut source);
        assert_eq!(rx.len(), 7);
    }
}
