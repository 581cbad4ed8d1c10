//! The scene's haptic device: opening it, and `softhaptic devices`.
//!
//! [`open`] builds the device a scene names (the simulated PHANTOM moved by its scripted hand,
//! a PHANTOM / Touch through OpenHaptics, an omega, delta, sigma or Falcon through Force
//! Dimension's SDK, or a SpaceMouse through hidapi) and writes back into the scene what the device
//! really is: its limits (the tighter of the device's and the preset's; for a SpaceMouse, the
//! preset's with a workspace that reaches the scene's box) and its label for the viewers, before
//! the recording and the `scene` message are made from the scene. A device that
//! cannot be opened stops the start with the device backend's error (which library was looked
//! for, where, and how to install it), before anything listens or records.
//!
//! [`listing`] is what `softhaptic devices` prints: the OpenHaptics library and each device it
//! can open (model, serial, limits, calibration), the Force Dimension SDK and each device it
//! sees (type, serial, the limits its type implies), the SpaceMice hidapi finds (and the udev
//! rule when hidraw is not readable), and the simulated device.

use std::fmt::Write as _;

use softhaptic_device::device::HapticDevice;
use softhaptic_device::forcedimension::{
    self as fd, ForceDimensionConfig, ForceDimensionDevice, ForceDimensionError,
};
use softhaptic_device::openhaptics::{
    self, Calibration, DeviceDescription, Discovery, OpenHapticsConfig, OpenHapticsDevice,
    OpenHapticsError,
};
use softhaptic_device::sim::{SimParams, SimulatedPhantom};
use softhaptic_device::spacemouse::script::ReportScript;
use softhaptic_device::spacemouse::{
    Connector, SpaceMouseDevice, SpaceMouseError, TransportError, hid,
};

/// Why the scene's device could not be opened.
#[derive(Debug, thiserror::Error)]
pub enum DeviceOpenError {
    #[error(transparent)]
    OpenHaptics(#[from] OpenHapticsError),
    #[error(transparent)]
    ForceDimension(#[from] ForceDimensionError),
    /// The SpaceMouse backend's reason, then what to do about it. Its text already holds every
    /// cause, so it names no `source`: a report that prints an error and then its causes would
    /// print the reason twice.
    #[error("{0}{advice}", advice = spacemouse_advice(.0))]
    SpaceMouse(SpaceMouseError),
    #[error("the SpaceMouse report script {0}")]
    ReportScript(String),
}

impl From<SpaceMouseError> for DeviceOpenError {
    fn from(e: SpaceMouseError) -> Self {
        Self::SpaceMouse(e)
    }
}

/// What to do when the SpaceMouse did not open: plug one in when none was found. A device that
/// would not open already says which udev rule fixes it, and a scene's bad setting names its
/// field.
fn spacemouse_advice(e: &SpaceMouseError) -> &'static str {
    match e {
        SpaceMouseError::Transport(
            TransportError::NotFound(_) | TransportError::Disconnected(_),
        ) => {
            "; plug one in (`softhaptic devices` lists what is found), or choose another device with --device"
        }
        _ => "",
    }
}

use crate::{DeviceKind, Scene};

/// The OpenHaptics configuration a scene describes.
pub fn openhaptics_config(scene: &Scene) -> OpenHapticsConfig {
    OpenHapticsConfig {
        name: scene.device_name.clone(),
        world_from_device: scene.world_from_device,
        scale: scene.device_scale,
        ..OpenHapticsConfig::new(scene.device_limits)
    }
}

/// The Force Dimension configuration a scene describes (its device name is the index, checked
/// when the scene or `--device` was read).
pub fn forcedimension_config(scene: &Scene) -> ForceDimensionConfig {
    ForceDimensionConfig {
        index: scene
            .device_name
            .as_deref()
            .and_then(|i| crate::file::parse_device_index(i).ok()),
        world_from_device: scene.world_from_device,
        scale: scene.device_scale,
        // These devices have no wrist to say how the tool is held: it points into the object
        // along the scene's press, as the simulated hand holds it, whatever the device's
        // placement.
        tool_in_device: scene.world_from_device.orientation.inverse()
            * scene.hand_script().tool_orientation(),
        ..ForceDimensionConfig::new(scene.device_limits)
    }
}

/// Opens the scene's device and records in the scene the limits it runs with and its label.
pub fn open(scene: &mut Scene) -> Result<Box<dyn HapticDevice>, DeviceOpenError> {
    match scene.device_kind {
        DeviceKind::Simulated => {
            scene.device_label = Some(format!("simulated {}", scene.device_limits.name));
            Ok(Box::new(SimulatedPhantom::with_params(
                scene.hand_script(),
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
        DeviceKind::Forcedimension => {
            let device = ForceDimensionDevice::open(&forcedimension_config(scene))?;
            scene.device_limits = device.limits();
            scene.device_label = Some(format!(
                "{} (Force Dimension)",
                device.description().label()
            ));
            Ok(Box::new(device))
        }
        DeviceKind::Spacemouse => {
            let (connector, source): (Box<dyn Connector>, String) = match &scene.spacemouse_script {
                Some(path) => (
                    Box::new(
                        ReportScript::from_file(path)
                            .map_err(DeviceOpenError::ReportScript)?
                            .connector(),
                    ),
                    format!("report stream {}", path.display()),
                ),
                None => (
                    Box::new(hid::HidConnector::new(scene.device_name.clone())),
                    "hidraw".to_owned(),
                ),
            };
            // The world takes a tip farther from its origin than the limits' workspace radius
            // (times a tolerance) for a broken reading and faults the tick. The puck's tool goes
            // wherever the scene's box lets it, and the box is placed around the object wherever
            // that is: the box's farthest corner is this device's reach.
            let rate = &scene.spacemouse_rate;
            let farthest_corner_m = rate
                .workspace_min_m
                .abs()
                .max(rate.workspace_max_m.abs())
                .length();
            let mut limits = scene.device_limits;
            limits.workspace_radius_m = limits.workspace_radius_m.max(farthest_corner_m);
            let device = SpaceMouseDevice::open(connector, scene.spacemouse_rate, limits)?;
            scene.device_limits = limits;
            scene.device_label = Some(format!(
                "{} (SpaceMouse, {source}; renders no force)",
                device.model().name
            ));
            scene.device_renders_force = device.renders_force();
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
    forcedimension_listing(&mut out, &fd::discover());
    spacemouse_listing(&mut out, &hid::list());
    let _ = writeln!(
        out,
        "simulated: always available (scene [device] kind = \"simulated\"; presets phantom_desktop, touch, omni, falcon, omega3, delta3, sigma7)"
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

/// The Force Dimension part of `softhaptic devices`.
pub fn forcedimension_listing(out: &mut String, discovery: &fd::Discovery) {
    match discovery {
        fd::Discovery::NoLibrary(e) => {
            let _ = writeln!(
                out,
                "Force Dimension (omega, delta, sigma, Falcon): not available"
            );
            let _ = writeln!(out, "  {e}");
        }
        fd::Discovery::Library {
            path,
            count,
            devices,
        } => {
            let _ = writeln!(
                out,
                "Force Dimension (omega, delta, sigma, Falcon): library {}",
                path.display()
            );
            match count {
                Ok(0) => {
                    let _ = writeln!(out, "  no device found");
                }
                Ok(_) => {}
                Err(e) => {
                    let _ = writeln!(out, "  the SDK could not count its devices: {e}");
                }
            }
            for (index, opened) in devices {
                match opened {
                    Ok(d) => {
                        let _ = writeln!(out, "  index {index}: {}", d.label());
                        match d.type_limits {
                            Some(l) => {
                                let _ = writeln!(
                                    out,
                                    "    limits: {:.1} N peak, {:.1} N continuous, {:.0} N/m stiffness, {:.1} N·s/m damping, workspace radius {:.3} m (scene preset {})",
                                    l.peak_force_n,
                                    l.continuous_force_n,
                                    l.max_stiffness_n_per_m,
                                    l.damping_n_s_per_m,
                                    l.workspace_radius_m,
                                    softhaptic_device::forcedimension::type_preset(d.type_id)
                                        .map_or("?", |(name, _)| name),
                                );
                            }
                            None => {
                                let _ = writeln!(
                                    out,
                                    "    limits: not known for this type: the scene's preset alone applies"
                                );
                            }
                        }
                    }
                    Err(e) => {
                        let _ = writeln!(out, "  index {index}: cannot be opened: {e}");
                    }
                }
            }
        }
    }
}

/// The SpaceMouse part of `softhaptic devices`.
pub fn spacemouse_listing(out: &mut String, listing: &hid::Listing) {
    let _ = writeln!(
        out,
        "SpaceMouse (input only, renders no force): hidapi on hidraw"
    );
    if let Some(e) = &listing.error {
        let _ = writeln!(out, "  hidapi could not list HID devices: {e}");
    }
    if listing.found.is_empty() && listing.error.is_none() {
        let _ = writeln!(out, "  none found");
    }
    for f in &listing.found {
        let name = f
            .model
            .unwrap_or("unknown 3Dconnexion product (not supported)");
        let state = match &f.opens {
            Ok(()) => "opens".to_owned(),
            Err(e) => format!("cannot be opened: {e}"),
        };
        let _ = writeln!(
            out,
            "  {name} [{:04x}:{:04x}] at {}, serial {}: {state}",
            f.vendor_id,
            f.product_id,
            f.path,
            f.serial.as_deref().unwrap_or("?"),
        );
    }
    let denied = listing.found.iter().any(|f| f.opens.is_err());
    if listing.hidraw_unreadable || denied {
        let _ = writeln!(
            out,
            "  /dev/hidraw* is not readable by this user: {}",
            hid::udev_hint().replace('\n', "\n  ")
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_spacemouse_that_is_not_found_says_so_once_with_what_to_do() {
        let e = DeviceOpenError::from(SpaceMouseError::Transport(TransportError::NotFound(
            "no 3Dconnexion device among the HID devices".into(),
        )));
        let text = softhaptic_io::logging::error_text(&e);
        assert_eq!(text.matches("no SpaceMouse found").count(), 1, "{text}");
        assert_eq!(text.matches("no 3Dconnexion device").count(), 1, "{text}");
        assert!(
            text.ends_with("choose another device with --device"),
            "{text}"
        );
        // A scene's setting is not fixed by plugging a device in.
        let e = DeviceOpenError::from(SpaceMouseError::Config(
            "dead_band must be in [0, 1)".into(),
        ));
        let text = softhaptic_io::logging::error_text(&e);
        assert!(!text.contains("plug one in"), "{text}");
        assert_eq!(text.matches("dead_band").count(), 1, "{text}");
    }

    #[test]
    fn the_spacemouse_listing_names_models_paths_and_the_udev_fix() {
        let mut out = String::new();
        spacemouse_listing(
            &mut out,
            &hid::Listing {
                found: vec![
                    hid::Found {
                        vendor_id: 0x256f,
                        product_id: 0xc635,
                        model: Some("SpaceMouse Compact"),
                        path: "/dev/hidraw3".into(),
                        serial: Some("A1B2".into()),
                        opens: Ok(()),
                    },
                    hid::Found {
                        vendor_id: 0x256f,
                        product_id: 0xc6ff,
                        model: None,
                        path: "/dev/hidraw4".into(),
                        serial: None,
                        opens: Err("Permission denied".into()),
                    },
                ],
                error: None,
                hidraw_unreadable: false,
            },
        );
        assert!(
            out.contains("SpaceMouse Compact [256f:c635] at /dev/hidraw3, serial A1B2: opens"),
            "{out}"
        );
        assert!(out.contains("unknown 3Dconnexion product"), "{out}");
        assert!(out.contains("Permission denied"), "{out}");
        assert!(out.contains(hid::UDEV_RULE_PATH), "{out}");

        let mut none = String::new();
        spacemouse_listing(
            &mut none,
            &hid::Listing {
                found: vec![],
                error: None,
                hidraw_unreadable: true,
            },
        );
        assert!(
            none.contains("none found") && none.contains("udevadm"),
            "{none}"
        );
    }
}
