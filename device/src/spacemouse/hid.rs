//! The SpaceMouse through hidapi on Linux's hidraw, and what `softhaptic devices` says of it.
//!
//! hidapi is built on its native Linux backend (hidraw through the kernel's interface, device
//! discovery from sysfs): nothing to install, no libusb, no libudev headers. Opening
//! `/dev/hidraw*` needs read access, which a udev rule gives to the desk's user and to the
//! `plugdev` group a service runs in ([`UDEV_RULE`]).

use std::path::Path;

use hidapi::{DeviceInfo, HidApi, HidDevice};

use super::report::{Model, find_model, is_3dconnexion_vendor};
use super::{Connector, Transport, TransportError};

/// Where the udev rule goes, and the rule: read access to the hidraw nodes of 3Dconnexion
/// devices (both vendor ids) for the user logged in at the seat (`uaccess`) and for the
/// `plugdev` group. The tag alone would leave out a station run as a systemd service, which has
/// no seat: its unit joins `plugdev` (`SupplementaryGroups=plugdev`) instead.
pub const UDEV_RULE_PATH: &str = "/etc/udev/rules.d/70-softhaptic-spacemouse.rules";
pub const UDEV_RULE: &str = concat!(
    "KERNEL==\"hidraw*\", ATTRS{idVendor}==\"256f\", MODE=\"0660\", GROUP=\"plugdev\", TAG+=\"uaccess\"\n",
    "KERNEL==\"hidraw*\", ATTRS{idVendor}==\"046d\", ATTRS{idProduct}==\"c6[0-5]?\", MODE=\"0660\", GROUP=\"plugdev\", TAG+=\"uaccess\"\n",
);

/// How to install the rule, for messages.
pub fn udev_hint() -> String {
    format!(
        "give your user access to the SpaceMouse with a udev rule: write\n{}to {UDEV_RULE_PATH}, then run `sudo udevadm control --reload && sudo udevadm trigger` and replug the device",
        UDEV_RULE
            .lines()
            .map(|l| format!("    {l}\n"))
            .collect::<String>()
    )
}

/// Opens the first listed SpaceMouse hidapi finds (optionally the one with a given serial).
pub struct HidConnector {
    api: Option<HidApi>,
    serial: Option<String>,
}

impl HidConnector {
    pub fn new(serial: Option<String>) -> Self {
        Self { api: None, serial }
    }
}

/// The multi-axis controller interface of a device (generic desktop page, usage 8); a receiver
/// also exposes keyboard-like interfaces that send nothing useful.
fn is_multi_axis(d: &DeviceInfo) -> bool {
    (d.usage_page() == 1 && d.usage() == 8) || d.usage_page() == 0
}

impl Connector for HidConnector {
    fn connect(&mut self) -> Result<(Box<dyn Transport>, &'static Model), TransportError> {
        let api = match &mut self.api {
            Some(api) => {
                api.refresh_devices()
                    .map_err(|e| TransportError::NotFound(format!("hidapi: {e}")))?;
                api
            }
            None => self.api.insert(
                HidApi::new().map_err(|e| TransportError::NotFound(format!("hidapi: {e}")))?,
            ),
        };
        let mut refused = Vec::new();
        for d in api.device_list() {
            let Some(model) = find_model(d.vendor_id(), d.product_id()) else {
                continue;
            };
            if !is_multi_axis(d) {
                continue;
            }
            if let Some(serial) = &self.serial
                && d.serial_number() != Some(serial.as_str())
            {
                continue;
            }
            match d.open_device(api) {
                Ok(device) => return Ok((Box::new(HidTransport { device }), model)),
                Err(e) => refused.push(format!(
                    "{} at {}: {e}",
                    model.name,
                    d.path().to_string_lossy()
                )),
            }
        }
        if refused.is_empty() {
            Err(TransportError::NotFound(format!(
                "no 3Dconnexion device among the HID devices{}",
                self.serial
                    .as_deref()
                    .map(|s| format!(" with serial {s:?}"))
                    .unwrap_or_default()
            )))
        } else {
            Err(TransportError::Open(format!(
                "a SpaceMouse is plugged in but could not be opened ({}); {}",
                refused.join("; "),
                udev_hint()
            )))
        }
    }
}

struct HidTransport {
    device: HidDevice,
}

impl Transport for HidTransport {
    fn read(&mut self, buf: &mut [u8], timeout_ms: i32) -> Result<usize, TransportError> {
        self.device
            .read_timeout(buf, timeout_ms)
            .map_err(|e| TransportError::Disconnected(e.to_string()))
    }
}

/// One 3Dconnexion HID device as `softhaptic devices` lists it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Found {
    pub vendor_id: u16,
    pub product_id: u16,
    /// The model's name, `None` for a 3Dconnexion product this backend does not know.
    pub model: Option<&'static str>,
    pub path: String,
    pub serial: Option<String>,
    /// `Ok` when it opened; otherwise why not.
    pub opens: Result<(), String>,
}

/// What hidapi sees of SpaceMice, and whether hidraw is readable at all.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Listing {
    pub found: Vec<Found>,
    /// hidapi could not start (the reason).
    pub error: Option<String>,
    /// `/dev/hidraw*` nodes exist and none is readable by this user.
    pub hidraw_unreadable: bool,
}

/// Lists the 3Dconnexion devices present.
pub fn list() -> Listing {
    let hidraw_unreadable = hidraw_unreadable(Path::new("/dev"));
    let api = match HidApi::new() {
        Ok(api) => api,
        Err(e) => {
            return Listing {
                found: Vec::new(),
                error: Some(e.to_string()),
                hidraw_unreadable,
            };
        }
    };
    let found = api
        .device_list()
        .filter(|d| is_3dconnexion_vendor(d.vendor_id()) && is_multi_axis(d))
        .filter(|d| {
            // The Logitech vendor id is shared with mice and keyboards: only its c6xx products
            // are 3Dconnexion's.
            d.vendor_id() != super::report::VENDOR_LOGITECH || d.product_id() >> 8 == 0xc6
        })
        .map(|d| Found {
            vendor_id: d.vendor_id(),
            product_id: d.product_id(),
            model: find_model(d.vendor_id(), d.product_id()).map(|m| m.name),
            path: d.path().to_string_lossy().into_owned(),
            serial: d.serial_number().map(str::to_owned),
            opens: d.open_device(&api).map(|_| ()).map_err(|e| e.to_string()),
        })
        .collect();
    Listing {
        found,
        error: None,
        hidraw_unreadable,
    }
}

/// True when `dir` holds `hidraw*` nodes and none of them can be opened for reading.
pub fn hidraw_unreadable(dir: &Path) -> bool {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return false;
    };
    let nodes: Vec<_> = entries
        .flatten()
        .filter(|e| e.file_name().to_string_lossy().starts_with("hidraw"))
        .collect();
    !nodes.is_empty() && nodes.iter().all(|e| std::fs::File::open(e.path()).is_err())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hidraw_is_unreadable_only_when_nodes_exist_and_none_opens() {
        let dir = std::env::temp_dir().join(format!("softhaptic-hidraw-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).expect("scratch directory");
        assert!(!hidraw_unreadable(&dir), "no nodes at all");
        // A node that cannot be opened (whoever runs the test, root included).
        std::os::unix::fs::symlink(dir.join("gone"), dir.join("hidraw0")).expect("symlink");
        std::fs::write(dir.join("other"), b"").expect("file");
        assert!(hidraw_unreadable(&dir));
        std::fs::write(dir.join("hidraw1"), b"").expect("file");
        assert!(!hidraw_unreadable(&dir), "one node opens");
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn the_udev_rule_covers_both_vendor_ids() {
        assert!(UDEV_RULE.contains("\"256f\"") && UDEV_RULE.contains("\"046d\""));
        // Every line opens the node to the seat's user and to the service's group.
        assert_eq!(UDEV_RULE.lines().count(), 2);
        for line in UDEV_RULE.lines() {
            assert!(
                line.contains("GROUP=\"plugdev\"") && line.contains("TAG+=\"uaccess\""),
                "{line}"
            );
            assert!(line.contains("MODE=\"0660\""), "{line}");
        }
        assert!(udev_hint().contains(UDEV_RULE_PATH) && udev_hint().contains("udevadm"));
        // Every listed Logitech-era product matches the rule's product pattern c6[0-5]?.
        for m in super::super::report::MODELS {
            if m.vendor_id == super::super::report::VENDOR_LOGITECH {
                assert!((0xc600..=0xc65f).contains(&m.product_id), "{m:?}");
            }
        }
    }
}
