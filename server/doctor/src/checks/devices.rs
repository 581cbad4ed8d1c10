//! The haptic devices: what OpenHaptics found (its devices, or why none), whether this user may
//! open the SpaceMouse's hidraw nodes, and the USB nodes of a Force Dimension device or Novint
//! Falcon, each with the udev rule that lets it.

use std::path::PathBuf;

use softhaptic_device::spacemouse::hid;

use super::Tree;
use crate::{Check, Verdict};

/// What OpenHaptics gave on this machine, reduced to text.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum OpenHapticsFacts {
    NoLibrary(String),
    Library {
        path: PathBuf,
        /// Each configuration tried, with its description or why it did not open.
        devices: Vec<(String, Result<String, String>)>,
    },
}

/// The devices found on this machine (the live part of the inspection).
#[derive(Debug, Clone)]
pub struct DeviceFacts {
    pub openhaptics: OpenHapticsFacts,
    pub spacemice: hid::Listing,
}

pub fn haptic_device_check(facts: &DeviceFacts) -> Check {
    let title = "Haptic device";
    let why = "without a device that opens, the server can run only the simulated device";
    let mut parts = Vec::new();
    let mut opened = Vec::new();
    let mut refused = Vec::new();
    match &facts.openhaptics {
        OpenHapticsFacts::NoLibrary(e) => {
            // The loader's message lists every place looked, one per line; `softhaptic devices`
            // prints it whole.
            let first = e.lines().next().unwrap_or("").split("; looked in").next();
            parts.push(format!(
                "OpenHaptics: not available ({}; `softhaptic devices` lists where it was looked for)",
                first.unwrap_or("").trim()
            ));
        }
        OpenHapticsFacts::Library { path, devices } => {
            parts.push(format!("OpenHaptics library {}", path.display()));
            for (name, result) in devices {
                match result {
                    Ok(d) => opened.push(format!("{name:?}: {d}")),
                    Err(e) => refused.push(format!("{name:?} cannot be opened: {e}")),
                }
            }
        }
    }
    let mice_open: Vec<String> = facts
        .spacemice
        .found
        .iter()
        .filter(|f| f.opens.is_ok())
        .map(|f| {
            format!(
                "{} at {} (input only, renders no force)",
                f.model.unwrap_or("3Dconnexion device"),
                f.path
            )
        })
        .collect();
    let found = {
        let mut all = parts;
        all.extend(opened.iter().cloned());
        all.extend(refused.iter().cloned());
        all.push(if facts.spacemice.found.is_empty() {
            "SpaceMouse: none found".to_owned()
        } else if mice_open.is_empty() {
            "SpaceMouse: found, cannot be opened (see HID access)".to_owned()
        } else {
            format!("SpaceMouse: {}", mice_open.join(", "))
        });
        all.join("; ")
    };
    if !opened.is_empty() || !mice_open.is_empty() {
        return Check::new("haptic_device", title, Verdict::Good, found, why, None);
    }
    let fix = if refused.is_empty() {
        "install the device driver and OpenHaptics (docs/devices.md, \"Setting up a PHANTOM or \
         a Touch\"), or set SOFTHAPTIC_HD_LIBRARY to its libHD.so; or plug in a SpaceMouse (input \
         only). `softhaptic devices` lists what is found"
    } else {
        "connect and power the device, check it in the vendor's Touch_Diagnostic, let your user \
         open it (`ls -l /dev/ttyACM*`: the dialout group or a udev rule, docs/devices.md \
         \"Setting up a PHANTOM or a Touch\"); a running softhaptic server holds the device, stop \
         it before this check"
    };
    Check::new(
        "haptic_device",
        title,
        Verdict::Warn,
        found,
        why,
        Some(fix.into()),
    )
}

pub fn hidraw_check(tree: &Tree, spacemice: &hid::Listing) -> Check {
    let title = "HID access (/dev/hidraw*)";
    let why = "a SpaceMouse is read through /dev/hidraw*, which by default only root may open";
    let nodes: Vec<String> = tree
        .entries("/dev")
        .into_iter()
        .filter(|n| n.starts_with("hidraw"))
        .collect();
    let readable: Vec<&String> = nodes
        .iter()
        .filter(|n| std::fs::File::open(tree.path(&format!("/dev/{n}"))).is_ok())
        .collect();
    let refused_mice: Vec<&hid::Found> = spacemice
        .found
        .iter()
        .filter(|f| f.opens.is_err())
        .collect();
    let udev = hid::udev_hint().replace('\n', " ");
    let udev = udev.split_whitespace().collect::<Vec<_>>().join(" ");
    if !refused_mice.is_empty() {
        let names: Vec<String> = refused_mice
            .iter()
            .map(|f| {
                format!(
                    "{} at {}: {}",
                    f.model.unwrap_or("3Dconnexion device"),
                    f.path,
                    f.opens.as_ref().err().map_or("", String::as_str)
                )
            })
            .collect();
        return Check::new(
            "hidraw",
            title,
            Verdict::Warn,
            format!("a SpaceMouse that cannot be opened: {}", names.join("; ")),
            why,
            Some(udev),
        );
    }
    if nodes.is_empty() {
        return Check::new(
            "hidraw",
            title,
            Verdict::Info,
            "no /dev/hidraw* nodes: no HID device is plugged in".into(),
            why,
            None,
        );
    }
    if readable.is_empty() {
        return Check::new(
            "hidraw",
            title,
            Verdict::Info,
            format!(
                "{} node{}, none readable by this user; only a SpaceMouse needs them",
                nodes.len(),
                if nodes.len() == 1 { "" } else { "s" }
            ),
            why,
            Some(format!("before using a SpaceMouse, {udev}")),
        );
    }
    Check::new(
        "hidraw",
        title,
        Verdict::Good,
        format!(
            "{} of {} nodes readable by this user",
            readable.len(),
            nodes.len()
        ),
        why,
        None,
    )
}

/// The USB nodes of the Force Dimension devices and Novint Falcons plugged in (found in sysfs by
/// their vendor and product ids): whether this user may open each, which the SDK needs.
pub fn forcedimension_usb_check(tree: &Tree) -> Check {
    use softhaptic_device::forcedimension as fd;
    let title = "Force Dimension USB access";
    let why = "the Force Dimension SDK opens the device's USB node (/dev/bus/usb/...), which by \
               default only root may write";
    let hex = |rel: String| {
        tree.read_line(&rel)
            .and_then(|t| u16::from_str_radix(t.trim(), 16).ok())
    };
    let number = |rel: String| {
        tree.read_line(&rel)
            .and_then(|t| t.trim().parse::<u32>().ok())
    };
    let mut found = Vec::new();
    for entry in tree.entries("/sys/bus/usb/devices") {
        let dir = format!("/sys/bus/usb/devices/{entry}");
        let (Some(vendor), Some(product)) = (
            hex(format!("{dir}/idVendor")),
            hex(format!("{dir}/idProduct")),
        ) else {
            continue;
        };
        if !fd::is_haptic_usb_device(vendor, product) {
            continue;
        }
        let node = match (
            number(format!("{dir}/busnum")),
            number(format!("{dir}/devnum")),
        ) {
            (Some(bus), Some(dev)) => format!("/dev/bus/usb/{bus:03}/{dev:03}"),
            _ => continue,
        };
        let opens = std::fs::OpenOptions::new()
            .read(true)
            .write(true)
            .open(tree.path(&node))
            .is_ok();
        let name = if vendor == fd::USB_VENDOR_FORCE_DIMENSION {
            "Force Dimension device"
        } else {
            "Novint Falcon"
        };
        found.push((
            format!("{name} [{vendor:04x}:{product:04x}] at {node}"),
            opens,
        ));
    }
    let udev = fd::udev_hint().replace('\n', " ");
    let udev = udev.split_whitespace().collect::<Vec<_>>().join(" ");
    if found.is_empty() {
        return Check::new(
            "forcedimension_usb",
            title,
            Verdict::Info,
            "no Force Dimension device or Novint Falcon on USB".into(),
            why,
            None,
        );
    }
    let refused: Vec<&str> = found
        .iter()
        .filter(|(_, opens)| !opens)
        .map(|(d, _)| d.as_str())
        .collect();
    if !refused.is_empty() {
        return Check::new(
            "forcedimension_usb",
            title,
            Verdict::Warn,
            format!("not writable by this user: {}", refused.join("; ")),
            why,
            Some(udev),
        );
    }
    let all: Vec<&str> = found.iter().map(|(d, _)| d.as_str()).collect();
    Check::new(
        "forcedimension_usb",
        title,
        Verdict::Good,
        format!("writable by this user: {}", all.join("; ")),
        why,
        None,
    )
}
