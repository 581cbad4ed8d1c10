//! A recorded session played back as a haptic device.
//!
//! [`ReplayDevice`] returns the recorded readings (and the recorded device errors) in their
//! order, one per [`HapticDevice::read`], and keeps the forces it is commanded, so that a replay
//! check can feed a recording through [`crate::world::HapticWorld::step`] and compare what comes
//! out with what was recorded. Everything is loaded before the first tick: `read` only indexes a
//! slice, so the device can also drive the real 1 kHz loop.
//!
//! The conversions between the device's in-memory types and the session-log records of
//! `softhaptic_proto::record` live here too: they are the only code that knows both, and they are
//! exact (every f64 is copied, never recomputed), which is what makes replay bit-identical.

use glam::{DQuat, DVec3};
use softhaptic_proto::record::{DeviceErrorRecord, DeviceRecord, SampleRecord};
use softhaptic_proto::{ContactFlags, Pose};

use softhaptic_proto::ContactState;

use crate::device::{DeviceError, DeviceLimits, DeviceSample, HapticDevice};
use crate::haptic_loop::TickRecord;

/// Plays recorded device readings back in order.
#[derive(Debug, Clone)]
pub struct ReplayDevice {
    limits: DeviceLimits,
    reads: Vec<Result<DeviceSample, DeviceError>>,
    /// Index of the next reading to return.
    next: usize,
    /// Forces commanded so far, one per `command_force` call, preallocated to the recording's
    /// length so the loop never allocates.
    commanded_n: Vec<DVec3>,
    /// The recorded device's refusals of the commands, by reading (empty: none refused).
    refusals: Vec<Option<DeviceError>>,
}

impl ReplayDevice {
    /// A device that returns `reads` in order, then [`DeviceError::Disconnected`] forever (the
    /// recording is over: the device is gone, and the loop renders zero force).
    pub fn new(limits: DeviceLimits, reads: Vec<Result<DeviceSample, DeviceError>>) -> Self {
        let commanded_n = Vec::with_capacity(reads.len());
        Self {
            limits,
            reads,
            next: 0,
            commanded_n,
            refusals: Vec::new(),
        }
    }

    /// A device replaying the device channel of a recording: its readings, and its refusals of
    /// the commands that followed them.
    pub fn from_records(limits: DeviceLimits, records: &[DeviceRecord]) -> Self {
        let mut device = Self::new(limits, records.iter().map(device_read).collect());
        if records.iter().any(|r| r.command_error.is_some()) {
            device.refusals = records
                .iter()
                .map(|r| r.command_error.as_ref().map(device_error))
                .collect();
        }
        device
    }

    /// Readings not yet returned.
    pub fn remaining(&self) -> usize {
        self.reads.len() - self.next
    }

    /// Whether every recorded reading has been returned.
    pub fn is_finished(&self) -> bool {
        self.next >= self.reads.len()
    }

    /// The forces commanded so far, in order (at most one per recorded reading).
    pub fn commanded_n(&self) -> &[DVec3] {
        &self.commanded_n
    }
}

impl HapticDevice for ReplayDevice {
    fn limits(&self) -> DeviceLimits {
        self.limits
    }

    fn read(&mut self) -> Result<DeviceSample, DeviceError> {
        match self.reads.get(self.next) {
            Some(r) => {
                self.next += 1;
                *r
            }
            None => Err(DeviceError::Disconnected),
        }
    }

    /// Keeps the command (up to the recording's length, so that it never allocates), and refuses
    /// it when the recorded device refused the command after the same reading.
    fn command_force(&mut self, force_n: DVec3) -> Result<(), DeviceError> {
        if self.commanded_n.len() < self.commanded_n.capacity() {
            self.commanded_n.push(force_n);
        }
        match self.next.checked_sub(1).and_then(|i| self.refusals.get(i)) {
            Some(Some(e)) => Err(*e),
            _ => Ok(()),
        }
    }
}

/// The record of one tick the loop offered to the session log, with the device's errors.
pub fn tick_device_record(t: &TickRecord) -> DeviceRecord {
    let read = match (t.sample, t.device_error) {
        (Some(s), _) => Ok(s),
        (None, e) => Err(e.unwrap_or(DeviceError::Disconnected)),
    };
    let mut r = device_record(&read, &t.contact);
    r.device_fault = t.device_fault;
    r.command_error = t.command_error.as_ref().map(error_record);
    r.lost_before = t.lost_before;
    r
}

/// The record of one tick from what the device returned and what the world computed.
pub fn device_record(
    read: &Result<DeviceSample, DeviceError>,
    contact: &ContactState,
) -> DeviceRecord {
    let (sample, device_error) = match read {
        Ok(s) => (Some(sample_record(s)), None),
        Err(e) => (None, Some(error_record(e))),
    };
    DeviceRecord {
        tick: contact.tick,
        time_ns: contact.time_ns,
        sample,
        device_fault: contact
            .flags
            .contains(softhaptic_proto::ContactFlags::DEVICE_FAULT),
        device_error,
        command_error: None,
        lost_before: 0,
        in_contact: contact.in_contact,
        depth_m: contact.depth_m,
        force_n: contact.force_n.to_array(),
        flags: contact.flags.bits(),
        guide: contact.guide,
    }
}

/// A device sample as recorded.
pub fn sample_record(s: &DeviceSample) -> SampleRecord {
    SampleRecord {
        time_ns: s.time_ns,
        tip_position_m: s.tip_in_world.position_m.to_array(),
        tip_orientation: s.tip_in_world.orientation.to_array(),
        tip_velocity_m_s: s.tip_velocity_m_s.to_array(),
        buttons: s.buttons,
        flags: s.flags.bits(),
    }
}

/// The recorded sample back as the device returned it, bit for bit.
pub fn device_sample(r: &SampleRecord) -> DeviceSample {
    DeviceSample {
        time_ns: r.time_ns,
        tip_in_world: Pose {
            position_m: DVec3::from_array(r.tip_position_m),
            orientation: DQuat::from_array(r.tip_orientation),
        },
        tip_velocity_m_s: DVec3::from_array(r.tip_velocity_m_s),
        buttons: r.buttons,
        flags: ContactFlags::from_bits_retain(r.flags),
    }
}

/// A device error as recorded.
pub fn error_record(e: &DeviceError) -> DeviceErrorRecord {
    match *e {
        DeviceError::Disconnected => DeviceErrorRecord::Disconnected,
        DeviceError::Timeout => DeviceErrorRecord::Timeout,
        DeviceError::ForceDisabled => DeviceErrorRecord::ForceDisabled,
        DeviceError::Driver(code) => DeviceErrorRecord::Driver { code },
        DeviceError::NeedsCalibration => DeviceErrorRecord::NeedsCalibration,
        DeviceError::Overrun => DeviceErrorRecord::Overrun,
        DeviceError::ForceLatched => DeviceErrorRecord::ForceLatched,
        DeviceError::Fatal => DeviceErrorRecord::Fatal,
        DeviceError::NeedsCalibrationReset => DeviceErrorRecord::NeedsCalibrationReset,
        DeviceError::CalibrationUpdating => DeviceErrorRecord::CalibrationUpdating,
    }
}

/// The recorded error back as the device returned it.
pub fn device_error(r: &DeviceErrorRecord) -> DeviceError {
    match *r {
        DeviceErrorRecord::Disconnected => DeviceError::Disconnected,
        DeviceErrorRecord::Timeout => DeviceError::Timeout,
        DeviceErrorRecord::ForceDisabled => DeviceError::ForceDisabled,
        DeviceErrorRecord::Driver { code } => DeviceError::Driver(code),
        DeviceErrorRecord::NeedsCalibration => DeviceError::NeedsCalibration,
        DeviceErrorRecord::Overrun => DeviceError::Overrun,
        DeviceErrorRecord::ForceLatched => DeviceError::ForceLatched,
        DeviceErrorRecord::Fatal => DeviceError::Fatal,
        DeviceErrorRecord::NeedsCalibrationReset => DeviceError::NeedsCalibrationReset,
        DeviceErrorRecord::CalibrationUpdating => DeviceError::CalibrationUpdating,
    }
}

/// What the device returned on a recorded tick: the sample, or the recorded error. A record with
/// neither (a file edited by hand) reads as a disconnected device, the safe interpretation.
pub fn device_read(r: &DeviceRecord) -> Result<DeviceSample, DeviceError> {
    match (&r.sample, &r.device_error) {
        (Some(s), _) => Ok(device_sample(s)),
        (None, Some(e)) => Err(device_error(e)),
        (None, None) => Err(DeviceError::Disconnected),
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
mod tests {
    use super::*;

    fn sample(k: u64) -> DeviceSample {
        DeviceSample {
            time_ns: k * 1_000_000,
            tip_in_world: Pose {
                position_m: DVec3::new(0.1 / 3.0, -1e-9 * k as f64, 0.0),
                orientation: DQuat::from_rotation_x(0.1),
            },
            tip_velocity_m_s: DVec3::new(f64::NAN, 1.0, -0.0),
            buttons: 3,
            flags: ContactFlags::MOTORS_WARM,
        }
    }

    #[test]
    fn replays_readings_and_errors_in_order_then_reports_disconnection() {
        let reads = vec![Ok(sample(0)), Err(DeviceError::Driver(-4)), Ok(sample(2))];
        let mut d = ReplayDevice::new(DeviceLimits::PHANTOM_DESKTOP, reads);
        assert_eq!(d.remaining(), 3);
        assert_eq!(d.read().unwrap().time_ns, 0);
        assert_eq!(d.read(), Err(DeviceError::Driver(-4)));
        assert_eq!(d.read().unwrap().time_ns, 2_000_000);
        assert!(d.is_finished());
        assert_eq!(d.read(), Err(DeviceError::Disconnected));
    }

    #[test]
    fn keeps_commanded_forces_without_growing() {
        let mut d = ReplayDevice::new(DeviceLimits::PHANTOM_DESKTOP, vec![Ok(sample(0))]);
        d.command_force(DVec3::X).unwrap();
        d.command_force(DVec3::Y).unwrap();
        assert_eq!(d.commanded_n(), &[DVec3::X]);
    }

    #[test]
    fn records_convert_back_bit_for_bit() {
        let s = sample(7);
        let back = device_sample(&sample_record(&s));
        assert_eq!(back.time_ns, s.time_ns);
        assert_eq!(back.buttons, s.buttons);
        let a = [
            s.tip_in_world.position_m.to_array(),
            s.tip_velocity_m_s.to_array(),
        ];
        let b = [
            back.tip_in_world.position_m.to_array(),
            back.tip_velocity_m_s.to_array(),
        ];
        for (x, y) in a.iter().flatten().zip(b.iter().flatten()) {
            assert_eq!(x.to_bits(), y.to_bits());
        }
        assert_eq!(back.tip_in_world.orientation, s.tip_in_world.orientation);
        for e in [
            DeviceError::Disconnected,
            DeviceError::Timeout,
            DeviceError::ForceDisabled,
            DeviceError::Driver(9),
        ] {
            assert_eq!(device_error(&error_record(&e)), e);
        }
    }
}
