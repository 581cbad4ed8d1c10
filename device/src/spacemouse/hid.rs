//! The SpaceMouse through hidapi on Linux's hidraw, and what `softhaptic devices` says of it.
//!
//! hidapi is built on its native Linux backend (hidraw through the kernel's interface, device
//! discovery from sysfs): nothing to install, no libusb, no libudev headers. Opening
//! `/dev/hidraw*` needs read access, which a udev rule gives to the desk's user and to the
//! `plugdev` group a service runs in ([`UDEV_RULE`]).

use hidapi::{DeviceInfo, HidApi, HidDevice};

use super::report::{Model, VENDOR_LOGITECH, find_model, is_3dconnexion_vendor};
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

/// What hidapi tells of one HID interface that the choice of a device depends on.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Interface<'a> {
    pub vendor_id: u16,
    pub product_id: u16,
    /// The top-level usage page and usage of the interface's report descriptor (0 and 0 when
    /// the kernel did not give the descriptor to hidapi).
    pub usage_page: u16,
    pub usage: u16,
    pub serial: Option<&'a str>,
}

impl<'a> Interface<'a> {
    fn of(d: &'a DeviceInfo) -> Self {
        Self {
            vendor_id: d.vendor_id(),
            product_id: d.product_id(),
            usage_page: d.usage_page(),
            usage: d.usage(),
            serial: d.serial_number(),
        }
    }
}

/// What to do with one HID interface.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Choice {
    /// Not a SpaceMouse's multi-axis interface: another vendor's device, a Logitech mouse or
    /// keyboard, or a receiver's keyboard-like interface. Passed over without a word.
    NotSpaceMouse,
    /// A 3Dconnexion multi-axis interface of a product not in [`super::report::MODELS`]:
    /// listed by its ids, never opened (its axes' scale is not known).
    UnknownProduct,
    /// A listed model, but not the one asked for by serial number.
    OtherSerial(&'static Model),
    /// Open it, and normalise its reports with this model's full scale.
    Open(&'static Model),
}

/// Chooses what to do with one HID interface, given the serial number asked for (if any).
/// Pure: [`HidConnector`] opens the first interface this says to open, and [`list`] lists
/// every one that is not [`Choice::NotSpaceMouse`].
pub fn choose(interface: &Interface<'_>, wanted_serial: Option<&str>) -> Choice {
    if !is_3dconnexion_vendor(interface.vendor_id) {
        return Choice::NotSpaceMouse;
    }
    // The Logitech vendor id is shared with mice and keyboards: only its c6xx products are
    // 3Dconnexion's.
    if interface.vendor_id == VENDOR_LOGITECH && interface.product_id >> 8 != 0xc6 {
        return Choice::NotSpaceMouse;
    }
    // The multi-axis controller (generic desktop page, usage 8); a receiver also exposes
    // keyboard-like interfaces that send nothing useful. Page 0: the kernel gave hidapi no
    // descriptor, so the interface is tried rather than passed over.
    let multi_axis =
        (interface.usage_page == 1 && interface.usage == 8) || interface.usage_page == 0;
    if !multi_axis {
        return Choice::NotSpaceMouse;
    }
    let Some(model) = find_model(interface.vendor_id, interface.product_id) else {
        return Choice::UnknownProduct;
    };
    match wanted_serial {
        Some(wanted) if interface.serial != Some(wanted) => Choice::OtherSerial(model),
        _ => Choice::Open(model),
    }
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
        let mut unknown = Vec::new();
        for d in api.device_list() {
            let model = match choose(&Interface::of(d), self.serial.as_deref()) {
                Choice::Open(model) => model,
                Choice::UnknownProduct => {
                    unknown.push(format!("{:04x}:{:04x}", d.vendor_id(), d.product_id()));
                    continue;
                }
                Choice::NotSpaceMouse | Choice::OtherSerial(_) => continue,
            };
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
            let unknown = if unknown.is_empty() {
                String::new()
            } else {
                format!(
                    " (3Dconnexion products this backend has no model for: {})",
                    unknown.join(", ")
                )
            };
            Err(TransportError::NotFound(format!(
                "no 3Dconnexion device among the HID devices{}{unknown}",
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

/// What hidapi sees of SpaceMice, and whether their nodes are readable.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Listing {
    pub found: Vec<Found>,
    /// hidapi could not start (the reason).
    pub error: Option<String>,
    /// SpaceMouse nodes were found and none of them opens: what the udev rule fixes. Other
    /// HID devices' nodes (keyboards, mice, security keys) do not count: that they are closed
    /// to this user is as it should be.
    pub hidraw_unreadable: bool,
}

/// Lists the 3Dconnexion devices present.
pub fn list() -> Listing {
    let api = match HidApi::new() {
        Ok(api) => api,
        Err(e) => {
            return Listing {
                found: Vec::new(),
                error: Some(e.to_string()),
                hidraw_unreadable: false,
            };
        }
    };
    let found: Vec<Found> = api
        .device_list()
        .filter_map(|d| {
            let model = match choose(&Interface::of(d), None) {
                Choice::NotSpaceMouse => return None,
                Choice::UnknownProduct => None,
                Choice::Open(model) | Choice::OtherSerial(model) => Some(model.name),
            };
            Some(Found {
                vendor_id: d.vendor_id(),
                product_id: d.product_id(),
                model,
                path: d.path().to_string_lossy().into_owned(),
                serial: d.serial_number().map(str::to_owned),
                opens: d.open_device(&api).map(|_| ()).map_err(|e| e.to_string()),
            })
        })
        .collect();
    Listing {
        hidraw_unreadable: hidraw_unreadable(&found),
        found,
        error: None,
    }
}

/// True when SpaceMouse nodes were found and none of them opened.
pub fn hidraw_unreadable(found: &[Found]) -> bool {
    !found.is_empty() && found.iter().all(|f| f.opens.is_err())
}

#[cfg(test)]
mod tests {
    use super::super::report::VENDOR_3DCONNEXION;
    use super::*;

    fn found(product_id: u16, opens: Result<(), String>) -> Found {
        Found {
            vendor_id: VENDOR_3DCONNEXION,
            product_id,
            model: find_model(VENDOR_3DCONNEXION, product_id).map(|m| m.name),
            path: format!("/dev/hidraw{}", product_id & 0xf),
            serial: None,
            opens,
        }
    }

    #[test]
    fn the_udev_hint_follows_the_spacemouse_nodes_alone() {
        let denied = || Err("Permission denied".to_owned());
        // No SpaceMouse: whatever other HID nodes there are, and however closed, no hint.
        assert!(!hidraw_unreadable(&[]));
        assert!(hidraw_unreadable(&[found(0xc635, denied())]));
        // Two SpaceMice, one of which opens: the desk works, no rule is missing.
        assert!(!hidraw_unreadable(&[
            found(0xc635, denied()),
            found(0xc631, Ok(()))
        ]));
        assert!(hidraw_unreadable(&[
            found(0xc635, denied()),
            found(0xc6ff, denied())
        ]));
    }

    fn interface(vendor_id: u16, product_id: u16) -> Interface<'static> {
        Interface {
            vendor_id,
            product_id,
            usage_page: 1,
            usage: 8,
            serial: Some("A1"),
        }
    }

    #[test]
    fn a_listed_models_multi_axis_interface_is_opened_with_its_own_scale() {
        let navigator = interface(VENDOR_LOGITECH, 0xc626);
        let Choice::Open(model) = choose(&navigator, None) else {
            panic!("{:?}", choose(&navigator, None));
        };
        assert_eq!((model.name, model.full_scale), ("SpaceNavigator", 350));
        let Choice::Open(model) = choose(&interface(VENDOR_LOGITECH, 0xc621), None) else {
            panic!("the SpaceBall 5000 is listed");
        };
        assert_eq!(model.full_scale, 512, "each model's own normaliser");
        // Every listed model is chosen, as itself.
        for m in super::super::report::MODELS {
            assert_eq!(
                choose(&interface(m.vendor_id, m.product_id), None),
                Choice::Open(m)
            );
        }
        // A descriptor the kernel did not give (page 0): tried, not passed over.
        let bare = Interface {
            usage_page: 0,
            usage: 0,
            ..navigator
        };
        assert!(matches!(choose(&bare, None), Choice::Open(_)));
    }

    #[test]
    fn other_interfaces_and_vendors_products_are_passed_over() {
        let compact = interface(VENDOR_3DCONNEXION, 0xc635);
        // A receiver's keyboard-like interface (generic desktop, keyboard) and a consumer
        // control interface.
        for (usage_page, usage) in [(1, 6), (1, 2), (0x0c, 1), (0xff00, 1)] {
            let other = Interface {
                usage_page,
                usage,
                ..compact
            };
            assert_eq!(choose(&other, None), Choice::NotSpaceMouse, "{other:?}");
        }
        // A Logitech mouse, and another vendor's device with a SpaceMouse's product id.
        assert_eq!(
            choose(&interface(VENDOR_LOGITECH, 0xc077), None),
            Choice::NotSpaceMouse
        );
        assert_eq!(
            choose(&interface(0x1234, 0xc626), None),
            Choice::NotSpaceMouse
        );
    }

    #[test]
    fn an_unknown_3dconnexion_product_is_listed_but_never_opened() {
        for (vendor, product) in [(VENDOR_3DCONNEXION, 0xc6ff), (VENDOR_LOGITECH, 0xc6aa)] {
            assert_eq!(
                choose(&interface(vendor, product), None),
                Choice::UnknownProduct
            );
            assert_eq!(
                choose(&interface(vendor, product), Some("A1")),
                Choice::UnknownProduct
            );
        }
    }

    #[test]
    fn a_serial_asked_for_passes_over_every_other_device() {
        let compact = interface(VENDOR_3DCONNEXION, 0xc635);
        assert!(matches!(choose(&compact, Some("A1")), Choice::Open(_)));
        assert!(matches!(
            choose(&compact, Some("B2")),
            Choice::OtherSerial(m) if m.name == "SpaceMouse Compact"
        ));
        // A device that reports no serial is not the one asked for.
        let anonymous = Interface {
            serial: None,
            ..compact
        };
        assert!(matches!(
            choose(&anonymous, Some("A1")),
            Choice::OtherSerial(_)
        ));
        assert!(matches!(choose(&anonymous, None), Choice::Open(_)));
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
