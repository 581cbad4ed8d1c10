//! The scene's haptic device: opening it, and `softhaptic devices`.
//!
//! [`open`] builds the device a scene names (the simulated PHANTOM moved by its scripted hand,
//! or a PHANTOM / Touch through OpenHaptics) and writes back into the scene what the device
//! really is: its limits (the tighter of the device's and the preset's) and its label for the
//! viewers, before the recording and the `scene` message are made from the scene. A device that
//! cannot be opened stops the start with the device backend's error (which library was looked
//! for, where, and how to install it), before anything listens or records.
//!
//! [`listing`] is what `softhaptic devices` prints: the OpenHaptics library and each device it
//! can open (model, serial, limits, calibration), and the simulated device.

use std::fmt::Write as _;

use softhaptic_device::device::HapticDevice;
use softhaptic_device::openhaptics::{
    self, Calibration, DeviceDescription, Discovery, OpenHapticsConfig, OpenHapticsDevice,
    OpenHapticsError,
};
use softhaptic_device::sim::{HandScript, SimParams, SimulatedPhantom};

use crate::scene::{DeviceKind, Scene};

/// The simulated hand's demonstration, repeated forever: approach, press, hold, slide, release
/// at the scene's press site.
pub fn hand_script(scene: &Scene) -> HandScript {
    let pose = scene.object_in_world;
    let (point, normal) = scene.press_site_in_object;
    let mut script = HandScript::press(
        pose.transform_point(point),
        pose.orientation * normal,
        scene.press_depth_m,
    );
    script.repeat = true;
    script
}

/// The OpenHaptics configuration a scene describes.
pub fn openhaptics_config(scene: &Scene) -> OpenHapticsConfig {
    OpenHapticsConfig {
        name: scene.device_name.clone(),
        world_from_device: scene.world_from_device,
        scale: scene.device_scale,
        ..OpenHapticsConfig::new(scene.device_limits)
    }
}

/// Opens the scene's device and records in the scene the limits it runs with and its label.
pub fn open(scene: &mut Scene) -> Result<Box<dyn HapticDevice>, OpenHapticsError> {
    match scene.device_kind {
        DeviceKind::Simulated => {
            scene.device_label = Some(format!("simulated {}", scene.device_limits.name));
            Ok(Box::new(SimulatedPhantom::with_params(
                hand_script(scene),
                SimParams {
                    limits: scene.device_limits,
                    ..SimParams::default()
                },
            )))
        }
        DeviceKind::Openhaptics => {
            let device = OpenHapticsDevice::open(&openhaptics_config(scene))?;
            let d = device.description();
            scene.device_limits = device.limits();
            scene.device_label = Some(format!(
                "{} (OpenHaptics, {}, serial {})",
                if d.model.is_empty() {
                    "haptic device"
                } else {
                    &d.model
                },
                d.display_name(),
                if d.serial.is_empty() { "?" } else { &d.serial },
            ));
            Ok(Box::new(device))
        }
    }
}

/// The `softhaptic devices` listing: the OpenHaptics library, every device it opens among the
/// default one and `names`, and the simulated device.
pub fn listing(names: &[String]) -> String {
    let mut out = String::new();
    match openhaptics::discover(names) {
        Discovery::NoLibrary(e) => {
            let _ = writeln!(out, "OpenHaptics (PHANTOM, Touch): not available");
            let _ = writeln!(out, "  {e}");
        }
        Discovery::Library { path, devices } => {
            let _ = writeln!(
                out,
                "OpenHaptics (PHANTOM, Touch): library {}",
                path.display()
            );
            for (name, result) in devices {
                match result {
                    Ok((d, calibration)) => describe(&mut out, &d, calibration),
                    Err(e) => {
                        let _ = writeln!(out, "  {name:?}: cannot be opened: {e}");
                    }
                }
            }
        }
    }
    let _ = writeln!(
        out,
        "simulated: always available (scene [device] kind = \"simulated\"; presets phantom_desktop, touch, omni)"
    );
    out
}

fn describe(out: &mut String, d: &DeviceDescription, calibration: Calibration) {
    let [lo, hi] = d.usable_workspace_mm;
    let size = hi - lo;
    let _ = writeln!(
        out,
        "  {:?}: {} by {}, serial {}",
        d.display_name(),
        if d.model.is_empty() { "?" } else { &d.model },
        if d.vendor.is_empty() { "?" } else { &d.vendor },
        if d.serial.is_empty() { "?" } else { &d.serial },
    );
    let _ = writeln!(
        out,
        "    limits: {:.2} N peak, {:.2} N continuous, {:.0} N/m stiffness, {:.1} N·s/m damping",
        d.max_force_n, d.continuous_force_n, d.max_stiffness_n_per_m, d.max_damping_n_s_per_m
    );
    let _ = writeln!(
        out,
        "    usable workspace: {:.0} × {:.0} × {:.0} mm",
        size.x, size.y, size.z
    );
    let styles = d.calibration_style_names().join(", ");
    let state = match calibration {
        Calibration::Ok => "calibrated".to_owned(),
        Calibration::NeedsUpdate => {
            "needs an update (done automatically when the loop starts)".to_owned()
        }
        Calibration::NeedsManualInput => {
            "needs calibration: put the stylus in its inkwell (or hold it at the reset position)"
                .to_owned()
        }
    };
    let _ = writeln!(out, "    calibration: {state} (styles: {styles})");
}
