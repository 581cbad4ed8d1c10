//! The tasks that feed every viewer: the 50 Hz frame task, which reads the loop's wait-free
//! publication, and the 1 Hz stats task with the trainee's metrics and the device's state.
//!
//! Both stop on their own signal (`stop`), before the viewers are closed: the session's final
//! metrics are those of the stopped loop, which only the live server's shutdown has
//! (`app::RunningServer::shutdown_with_metrics`, in the crate above), and it sends them
//! ([`send_final_metrics`]) to viewers that are still connected. Were this task to send the
//! loop's latest publication when the viewers' shutdown comes, it would send metrics up to 100
//! ticks old while the loop still ran, on a channel the viewers were leaving at that moment.

use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::time::Duration;

use axum::extract::ws::Utf8Bytes;
use softhaptic_device::device::DeviceError;
use softhaptic_device::haptic_loop::HapticLoop;
use softhaptic_device::inclusion::InclusionField;
use softhaptic_device::metrics::TraineeMetrics;
use softhaptic_device::stats::LoopStats;
use softhaptic_proto::CalibrationTable;
use softhaptic_proto::contact::{ContactState, Pose};
use softhaptic_proto::wire::{
    ComputeUs, ContactFrame, DeviceStatus, MetricsMessage, PeriodErrorUs, ServerMessage,
    StatsMessage,
};

use tokio::sync::watch;

use super::{EncodedFrame, StreamCounters, StreamHub};

/// The inclusions of an object and its pose, to tell each frame the force ratio at its contact.
pub struct FrameInclusions {
    pub field: InclusionField,
    pub object_in_world: Pose,
}

impl FrameInclusions {
    /// The force ratio at `state`'s contact, as the loop's force model had it at that tick (the
    /// same field at the same contact point, normal and depth, in the object's frame); `None`
    /// out of contact.
    pub fn ratio(&self, state: &ContactState) -> Option<f64> {
        if !state.in_contact {
            return None;
        }
        let o = &self.object_in_world;
        let point = o.inverse_transform_point(state.contact_point_m);
        let normal = o.orientation.inverse() * state.normal;
        let ratio = self.field.load(point, normal, state.depth_m).ratio;
        ratio.is_finite().then_some(ratio)
    }
}

/// Reads the loop's latest contact every `period` and broadcasts it, until `stop` turns true.
/// With `inclusions`, each frame in contact says the inclusions' force ratio there.
pub async fn frame_task(
    haptic_loop: Arc<HapticLoop>,
    calibration: CalibrationTable,
    inclusions: Option<FrameInclusions>,
    hub: Arc<StreamHub>,
    period: Duration,
    mut stop: watch::Receiver<bool>,
) {
    let mut interval = tokio::time::interval(period);
    // After a stall, continue at the normal rate rather than bursting the missed frames.
    interval.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
    let mut seq: u64 = 0;
    loop {
        tokio::select! {
            _ = interval.tick() => {}
            _ = stop.changed() => break,
        }
        let state = haptic_loop.latest_contact();
        let deformed_radius_m = if state.in_contact {
            calibration.deformed_radius_m(state.depth_m)
        } else {
            0.0
        };
        hub.latest_time_ns.store(state.time_ns, Ordering::Relaxed);
        let mut frame = ContactFrame::from_state(&state, seq, deformed_radius_m, 0);
        frame.inclusion_force_ratio = inclusions.as_ref().and_then(|i| i.ratio(&state));
        match EncodedFrame::new(&frame) {
            Ok(encoded) => {
                // No receivers is not an error: frames are simply not needed.
                let _ = hub.frames.send(Arc::new(encoded));
                hub.counters.frames_sent.fetch_add(1, Ordering::Relaxed);
            }
            Err(e) => tracing::error!(error = %e, seq, "could not encode a contact frame"),
        }
        seq += 1;
    }
}

/// The `stats` message for the loop's current summary and the stream's counters.
pub fn stats_message(
    loop_stats: &LoopStats,
    counters: &StreamCounters,
    device: DeviceStatus,
) -> StatsMessage {
    let us = |ns: u64| ns as f64 * 1e-3;
    StatsMessage {
        loop_rate_hz: loop_stats.loop_rate_hz,
        period_error_us: PeriodErrorUs {
            p50: us(loop_stats.period_error_p50_ns),
            p99: us(loop_stats.period_error_p99_ns),
            p999: us(loop_stats.period_error_p999_ns),
            max: us(loop_stats.period_error_max_ns),
        },
        overruns: loop_stats.overruns,
        standby_ticks: loop_stats.standby_ticks,
        compute_us: ComputeUs {
            p50: us(loop_stats.compute_p50_ns),
            p99: us(loop_stats.compute_p99_ns),
            max: us(loop_stats.compute_max_ns),
        },
        viewers: counters.viewers.load(Ordering::Relaxed),
        dropped_frames: counters.dropped_frames.load(Ordering::Relaxed),
        device,
    }
}

/// The device's state for viewers, from its error on the last tick.
pub fn device_status(error: Option<DeviceError>) -> DeviceStatus {
    match error {
        None => DeviceStatus::Ok,
        Some(DeviceError::Disconnected) => DeviceStatus::Disconnected,
        Some(DeviceError::Timeout) => DeviceStatus::NotAnswering,
        Some(DeviceError::ForceDisabled) => DeviceStatus::ForceDisabled,
        Some(DeviceError::NeedsCalibration) => DeviceStatus::NeedsCalibration,
        Some(DeviceError::Overrun) => DeviceStatus::Overrun,
        Some(DeviceError::Driver(_)) => DeviceStatus::DriverError,
        Some(DeviceError::ForceLatched) => DeviceStatus::ForceLatched,
        Some(DeviceError::Fatal) => DeviceStatus::Failed,
        Some(DeviceError::NeedsCalibrationReset) => DeviceStatus::NeedsCalibrationReset,
        Some(DeviceError::CalibrationUpdating) => DeviceStatus::CalibrationUpdating,
    }
}

/// How often the stats task looks at the device's state: a change is logged and sent to the
/// viewers at once rather than with the next second's stats.
const DEVICE_STATUS_POLL: Duration = Duration::from_millis(50);

/// Broadcasts `stats` and `metrics` every `period`, until `stop` turns true (the final
/// `metrics` are the server's to send, once the loop has stopped: [`send_final_metrics`]).
pub async fn stats_task(
    haptic_loop: Arc<HapticLoop>,
    hub: Arc<StreamHub>,
    period: Duration,
    mut stop: watch::Receiver<bool>,
) {
    let mut interval = tokio::time::interval(period);
    interval.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
    // The first tick fires at once; the loop has no statistics yet then.
    interval.tick().await;
    let mut poll = tokio::time::interval(DEVICE_STATUS_POLL.min(period));
    poll.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
    let mut device = DeviceStatus::Ok;
    loop {
        tokio::select! {
            _ = interval.tick() => {}
            _ = poll.tick() => {
                // The most severe error since the last poll, not the last tick's: a fault of a
                // tick or two between polls is logged and shown (and the next poll, if it is
                // over, says the device is back).
                let error = haptic_loop.take_device_error();
                let now = device_status(error);
                if now == device {
                    continue;
                }
                // One line per change of state, never per tick; the text a person reads.
                match error {
                    Some(e) => tracing::warn!(error = %e, "haptic device: {}", now.message()),
                    None => tracing::info!("haptic device: back, force ramps in again"),
                }
                device = now;
            }
            _ = stop.changed() => break,
        }
        let message = stats_message(&haptic_loop.stats(), &hub.counters, device);
        match ServerMessage::Stats(message).encode() {
            Ok(text) => {
                let _ = hub.stats.send(Utf8Bytes::from(text));
            }
            Err(e) => tracing::error!(error = %e, "could not encode stats"),
        }
        send_metrics(&hub, &haptic_loop.metrics(), false);
    }
}

/// The `metrics` message of the trainee's metrics.
pub fn metrics_message(m: &TraineeMetrics, is_final: bool) -> MetricsMessage {
    let flags_raised = m
        .flag_onsets
        .iter()
        .enumerate()
        .filter(|(_, n)| **n > 0)
        .filter_map(|(bit, n)| {
            let flag = softhaptic_proto::ContactFlags::from_bits_retain(1 << bit);
            softhaptic_proto::wire::flag_name(flag).map(|name| (name.to_owned(), *n))
        })
        .collect();
    MetricsMessage {
        peak_force_n: m.peak_force_n,
        peak_force_time_s: m.peak_force_time_s,
        safe_force_n: m.safe_force_n,
        time_above_safe_s: m.time_above_safe_s,
        time_in_contact_s: m.time_in_contact_s,
        path_length_in_contact_m: m.path_length_in_contact_m,
        mean_squared_jerk_m2_s6: m.mean_squared_jerk_m2_s6,
        pushes: m.pushes,
        device_fault_ticks: m.device_fault_ticks,
        flags_raised,
        ticks: m.ticks,
        is_final,
    }
}

/// Sends every viewer the session's final `metrics`: those of the stopped loop, over every tick
/// it ran (the ones the recording closes with). Sent before the viewers are told to close, so
/// each viewer's queue holds them when it closes, and drains them first.
pub fn send_final_metrics(hub: &StreamHub, m: &TraineeMetrics) {
    send_metrics(hub, m, true);
}

fn send_metrics(hub: &StreamHub, m: &TraineeMetrics, is_final: bool) {
    match ServerMessage::Metrics(metrics_message(m, is_final)).encode() {
        Ok(text) => {
            let _ = hub.stats.send(Utf8Bytes::from(text));
        }
        Err(e) => tracing::error!(error = %e, "could not encode the metrics"),
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
mod tests {
    use super::*;

    #[test]
    fn stats_convert_nanoseconds_to_microseconds() {
        let stats = LoopStats {
            loop_rate_hz: 999.5,
            period_error_p50_ns: 2_500,
            period_error_p99_ns: 20_000,
            period_error_p999_ns: 48_000,
            period_error_max_ns: 130_000,
            overruns: 3,
            standby_ticks: 11,
            compute_p50_ns: 12_000,
            compute_p99_ns: 40_000,
            compute_max_ns: 95_000,
            ..LoopStats::default()
        };
        let counters = StreamCounters::default();
        counters.viewers.store(2, Ordering::Relaxed);
        counters.dropped_frames.store(7, Ordering::Relaxed);
        let m = stats_message(&stats, &counters, DeviceStatus::Disconnected);
        assert_eq!(m.device, DeviceStatus::Disconnected);
        assert_eq!(m.period_error_us.p50, 2.5);
        assert_eq!(m.period_error_us.max, 130.0);
        assert_eq!(m.compute_us.p99, 40.0);
        assert_eq!((m.viewers, m.dropped_frames, m.overruns), (2, 7, 3));
        assert_eq!(m.standby_ticks, 11);
    }
}
