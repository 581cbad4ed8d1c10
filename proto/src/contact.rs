//! The contact state the 1 kHz loop publishes every tick.

use glam::{DQuat, DVec3};
use serde::{Deserialize, Serialize};

/// A rigid pose: where a frame's origin is, and how it is turned, in its parent frame.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Pose {
    pub position_m: DVec3,
    pub orientation: DQuat,
}

impl Pose {
    pub const IDENTITY: Pose = Pose {
        position_m: DVec3::ZERO,
        orientation: DQuat::IDENTITY,
    };

    /// A pose with no rotation.
    pub fn from_position(position_m: DVec3) -> Self {
        Pose {
            position_m,
            orientation: DQuat::IDENTITY,
        }
    }

    /// Maps a point given in this pose's frame into the parent frame.
    pub fn transform_point(&self, point: DVec3) -> DVec3 {
        self.position_m + self.orientation * point
    }

    /// Maps a point given in the parent frame into this pose's frame.
    pub fn inverse_transform_point(&self, point: DVec3) -> DVec3 {
        self.orientation.inverse() * (point - self.position_m)
    }

    /// True when every component is finite.
    pub fn is_finite(&self) -> bool {
        self.position_m.is_finite() && self.orientation.is_finite()
    }
}

bitflags::bitflags! {
    /// Which limits acted on, or which validity bounds were passed by, one tick's force.
    #[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default, Serialize, Deserialize)]
    #[serde(transparent)]
    pub struct ContactFlags: u32 {
        /// Depth beyond the range where the active contact model is known to be accurate.
        const BEYOND_VALID_DEPTH = 1 << 0;
        /// Tool inclination to the contact normal beyond the model's valid angle.
        const BEYOND_VALID_INCLINATION = 1 << 1;
        /// Force magnitude clipped at the device's peak force.
        const SATURATED = 1 << 2;
        /// Contact stiffness capped at the device's stable stiffness (linear extension beyond δ*).
        const STIFFNESS_CAPPED = 1 << 3;
        /// The device reported a non-finite or out-of-range sample, or disappeared: force is zero.
        const DEVICE_FAULT = 1 << 4;
        /// Force is ramping up after contact began or after a fault cleared.
        const RAMPING = 1 << 5;
        /// The passivity controller added damping to remove energy the loop would have created.
        const PASSIVITY_DAMPING = 1 << 6;
        /// The colliding vertex normals cancelled; the normal fell back to a defined direction.
        const DEGENERATE_NORMAL = 1 << 7;
        /// The force was scaled down to hold the motors' RMS force at the device's continuous
        /// rating (a long, hard press).
        const CONTINUOUS_FORCE_LIMITED = 1 << 8;
        /// The tool was pushed past what the collision can measure (deeper than the tip's
        /// height, or through to the far side of a thin part): the contact is held against the
        /// surface on the side the tool entered, its depth measured along that side's normal,
        /// until the tool comes back out on that side.
        const PUSHED_THROUGH = 1 << 9;
        /// The device's motors are warm: the driver asks for less force, and the force is held
        /// to the device's continuous rating until they have cooled.
        const MOTORS_WARM = 1 << 10;
        /// The tip is outside the device's usable workspace (inside the box it can reach, where
        /// its readings are less accurate).
        const OUTSIDE_WORKSPACE = 1 << 11;
        /// The tick came late (the servo thread stalled): the force's change since the last
        /// tick was limited to what the device renders stably over so long an interval.
        const LATE_TICK_LIMITED = 1 << 12;
    }
}

/// Everything one haptic tick knows about the contact. Plain `Copy` data so that it can cross
/// a wait-free buffer without allocation.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ContactState {
    /// Tick counter since the loop started.
    pub tick: u64,
    /// Device time of the sample, nanoseconds since the loop started.
    pub time_ns: u64,
    /// The tool tip's pose in the world frame.
    pub tip_in_world: Pose,
    /// The tool tip's linear velocity in the world frame.
    pub tip_velocity_m_s: DVec3,
    /// Device button bits.
    pub buttons: u32,
    /// Whether the tool touches the object this tick.
    pub in_contact: bool,
    /// Indentation depth δ along the contact normal (0 out of contact).
    pub depth_m: f64,
    /// Contact normal in the world frame, unit length, pointing out of the object.
    pub normal: DVec3,
    /// Centre of the contact on the undeformed surface, world frame.
    pub contact_point_m: DVec3,
    /// Radius a of the contact circle.
    pub contact_radius_m: f64,
    /// Force commanded to the device, world frame (after damping and every safety limit).
    pub force_n: DVec3,
    /// Which limits acted and which validity bounds were passed.
    pub flags: ContactFlags,
    /// The guidance's pull this tick (`None` in a session without a guide).
    pub guide: Option<crate::GuideState>,
}

impl ContactState {
    /// The state before the first tick: no contact, zero force.
    pub const IDLE: ContactState = ContactState {
        tick: 0,
        time_ns: 0,
        tip_in_world: Pose::IDENTITY,
        tip_velocity_m_s: DVec3::ZERO,
        buttons: 0,
        in_contact: false,
        depth_m: 0.0,
        normal: DVec3::Y,
        contact_point_m: DVec3::ZERO,
        contact_radius_m: 0.0,
        force_n: DVec3::ZERO,
        flags: ContactFlags::empty(),
        guide: None,
    };
}

impl Default for ContactState {
    fn default() -> Self {
        Self::IDLE
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
mod tests {
    use super::*;

    #[test]
    fn pose_round_trips_points() {
        let pose = Pose {
            position_m: DVec3::new(0.1, 0.2, 0.3),
            orientation: DQuat::from_rotation_z(0.7),
        };
        let p = DVec3::new(-0.4, 0.5, 2.0);
        let back = pose.inverse_transform_point(pose.transform_point(p));
        assert!((back - p).length() < 1e-12);
    }

    #[test]
    fn contact_state_serialises_with_named_units() {
        let s = serde_json::to_string(&ContactState::IDLE).unwrap();
        assert!(s.contains("depth_m") && s.contains("force_n"));
        let back: ContactState = serde_json::from_str(&s).unwrap();
        assert_eq!(back, ContactState::IDLE);
    }
}
