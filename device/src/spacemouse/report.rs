//! The SpaceMouse family's HID reports: which products there are, how each lays out its axes,
//! and how a report's bytes become normalised puck deflections.
//!
//! Two layouts exist (docs/devices.md). Older devices send three reports: id 1 with the translation
//! x, y, z, id 2 with the rotation rx, ry, rz (each six bytes: three little-endian `i16`), and
//! id 3 with the button bitmap. Newer and wireless devices send all six axes in one report id 1
//! twelve bytes long, and the buttons in id 3 as before. Raw values reach about ±350 (a model's
//! own full scale is in [`Model::full_scale`]); [`Parser`] divides by it and clamps to ±1 so a
//! scene's gain means the same on every model.
//!
//! The axes are the HID's: x to the right, y towards the user, z down (pushing the puck gives
//! +z); the rotations are about those axes. [`Axes`] keeps that frame; the rate control maps it
//! into the world.

/// 3Dconnexion's vendor id from the Logitech years.
pub const VENDOR_LOGITECH: u16 = 0x046d;
/// 3Dconnexion's own vendor id (newer devices).
pub const VENDOR_3DCONNEXION: u16 = 0x256f;

/// One SpaceMouse product.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Model {
    pub vendor_id: u16,
    pub product_id: u16,
    pub name: &'static str,
    /// The raw value of a full deflection on every axis (the normaliser).
    pub full_scale: i16,
}

/// The products the backend opens, as spacenavd's device table lists them for USB. A product
/// not listed is refused by name and id rather than guessed at.
///
/// Where each full scale comes from:
/// - 350, every model but one: `docs/devices.md` (SpaceMouse, "Scale": raw values reach about
///   ±350), the same divisor OpenSCAD's hidapi driver applies to both
///   layouts of every model it opens (`src/input/HidApiInputDriver.cc`, `hidapi_sm_decode_axis`).
///   A unit that exceeds it is clamped to ±1 ([`Parser`]), so a model that reaches a little
///   further loses only the last part of its travel.
/// - 512, the SpaceBall 5000 (USB): the one exception `docs/devices.md` names, a figure no
///   published table gives; 512 is an assumption, chosen so that its larger travel is not
///   clamped away. The raw reports of a full push on one (`sudo hexdump -C /dev/hidrawN`, the
///   little-endian `i16` after each report id) would settle it.
pub const MODELS: &[Model] = &[
    model(VENDOR_LOGITECH, 0xc603, "SpaceMouse Plus XT", 350),
    model(VENDOR_LOGITECH, 0xc605, "CadMan", 350),
    model(VENDOR_LOGITECH, 0xc606, "SpaceMouse Classic", 350),
    // The one model with another scale: see above.
    model(VENDOR_LOGITECH, 0xc621, "SpaceBall 5000", 512),
    model(VENDOR_LOGITECH, 0xc623, "SpaceTraveler", 350),
    model(VENDOR_LOGITECH, 0xc625, "SpacePilot", 350),
    model(VENDOR_LOGITECH, 0xc626, "SpaceNavigator", 350),
    model(VENDOR_LOGITECH, 0xc627, "SpaceExplorer", 350),
    model(VENDOR_LOGITECH, 0xc628, "SpaceNavigator for Notebooks", 350),
    model(VENDOR_LOGITECH, 0xc629, "SpacePilot Pro", 350),
    model(VENDOR_LOGITECH, 0xc62b, "SpaceMouse Pro", 350),
    model(VENDOR_LOGITECH, 0xc62e, "SpaceMouse Wireless (cable)", 350),
    model(
        VENDOR_LOGITECH,
        0xc62f,
        "SpaceMouse Wireless (receiver)",
        350,
    ),
    model(
        VENDOR_3DCONNEXION,
        0xc631,
        "SpaceMouse Pro Wireless (cable)",
        350,
    ),
    model(
        VENDOR_3DCONNEXION,
        0xc632,
        "SpaceMouse Pro Wireless (receiver)",
        350,
    ),
    model(VENDOR_3DCONNEXION, 0xc633, "SpaceMouse Enterprise", 350),
    model(VENDOR_3DCONNEXION, 0xc635, "SpaceMouse Compact", 350),
    model(VENDOR_3DCONNEXION, 0xc636, "SpaceMouse Module", 350),
    model(
        VENDOR_3DCONNEXION,
        0xc652,
        "3Dconnexion Universal Receiver",
        350,
    ),
];

const fn model(vendor_id: u16, product_id: u16, name: &'static str, full_scale: i16) -> Model {
    Model {
        vendor_id,
        product_id,
        name,
        full_scale,
    }
}

/// The listed model with these ids, if any.
pub fn find_model(vendor_id: u16, product_id: u16) -> Option<&'static Model> {
    MODELS
        .iter()
        .find(|m| m.vendor_id == vendor_id && m.product_id == product_id)
}

/// True for a vendor id 3Dconnexion devices use (a product of theirs not in [`MODELS`] is
/// reported as unknown rather than ignored).
pub fn is_3dconnexion_vendor(vendor_id: u16) -> bool {
    vendor_id == VENDOR_LOGITECH || vendor_id == VENDOR_3DCONNEXION
}

/// The puck's deflection, each axis normalised to [-1, 1], in the HID's frame (x right, y
/// towards the user, z down).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Axes {
    pub translation: [f64; 3],
    pub rotation: [f64; 3],
}

/// What one report changed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ReportUpdate {
    /// Report id 1 of the three-report layout.
    Translation([f64; 3]),
    /// Report id 2 of the three-report layout.
    Rotation([f64; 3]),
    /// Report id 1 of the combined layout: all six axes.
    SixAxes(Axes),
    /// Report id 3: the button bitmap, bit 0 the first button.
    Buttons(u32),
    /// A report the backend has no use for (LED state, battery level, vendor reports).
    Ignored(u8),
}

/// Why a report's bytes were refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum ReportError {
    #[error("an empty HID report")]
    Empty,
    #[error("HID report id {id} is {len} bytes long; it needs at least {needed}")]
    Short { id: u8, len: usize, needed: usize },
}

/// Bytes of an axis report: the id and three `i16`.
const THREE_AXES_LEN: usize = 1 + 6;
/// Bytes of the combined report: the id and six `i16`.
const SIX_AXES_LEN: usize = 1 + 12;

/// Turns one model's reports into [`ReportUpdate`]s.
#[derive(Debug, Clone, Copy)]
pub struct Parser {
    full_scale: f64,
}

impl Parser {
    pub fn new(model: &Model) -> Self {
        Self {
            full_scale: f64::from(model.full_scale.max(1)),
        }
    }

    /// Parses one report as hidapi returns it (the report id first). Never panics: a short or
    /// unknown report is an error or [`ReportUpdate::Ignored`].
    pub fn parse(&self, report: &[u8]) -> Result<ReportUpdate, ReportError> {
        let (&id, _) = report.split_first().ok_or(ReportError::Empty)?;
        match id {
            1 if report.len() >= SIX_AXES_LEN => {
                let [x, y, z, rx, ry, rz] = self.axes::<6>(report);
                Ok(ReportUpdate::SixAxes(Axes {
                    translation: [x, y, z],
                    rotation: [rx, ry, rz],
                }))
            }
            1 | 2 => {
                if report.len() < THREE_AXES_LEN {
                    return Err(ReportError::Short {
                        id,
                        len: report.len(),
                        needed: THREE_AXES_LEN,
                    });
                }
                let axes = self.axes::<3>(report);
                Ok(if id == 1 {
                    ReportUpdate::Translation(axes)
                } else {
                    ReportUpdate::Rotation(axes)
                })
            }
            3 => {
                if report.len() < 2 {
                    return Err(ReportError::Short {
                        id,
                        len: report.len(),
                        needed: 2,
                    });
                }
                // Up to four bytes of bitmap (the SpaceMouse Enterprise has 31 buttons).
                let bits = report[1..]
                    .iter()
                    .take(4)
                    .enumerate()
                    .fold(0u32, |acc, (i, b)| acc | (u32::from(*b) << (8 * i)));
                Ok(ReportUpdate::Buttons(bits))
            }
            other => Ok(ReportUpdate::Ignored(other)),
        }
    }

    /// The first `N` little-endian `i16` after the id, normalised and clamped to [-1, 1].
    fn axes<const N: usize>(&self, report: &[u8]) -> [f64; N] {
        std::array::from_fn(|i| {
            let raw = i16::from_le_bytes([report[1 + 2 * i], report[2 + 2 * i]]);
            (f64::from(raw) / self.full_scale).clamp(-1.0, 1.0)
        })
    }
}

/// The puck's state as the reports so far left it.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct PuckState {
    pub axes: Axes,
    pub buttons: u32,
}

impl PuckState {
    /// Applies one report's update.
    pub fn apply(&mut self, update: ReportUpdate) {
        match update {
            ReportUpdate::Translation(t) => self.axes.translation = t,
            ReportUpdate::Rotation(r) => self.axes.rotation = r,
            ReportUpdate::SixAxes(a) => self.axes = a,
            ReportUpdate::Buttons(b) => self.buttons = b,
            ReportUpdate::Ignored(_) => {}
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn navigator() -> Parser {
        Parser::new(find_model(VENDOR_LOGITECH, 0xc626).expect("listed"))
    }

    fn le(values: &[i16]) -> Vec<u8> {
        values.iter().flat_map(|v| v.to_le_bytes()).collect()
    }

    #[test]
    fn three_report_layout_gives_each_axis_with_its_sign() {
        let p = navigator();
        for axis in 0..3 {
            for sign in [-1i16, 1] {
                let mut raw = [0i16; 3];
                raw[axis] = sign * 175;
                let mut t = vec![1u8];
                t.extend(le(&raw));
                let mut expected = [0.0; 3];
                expected[axis] = f64::from(sign) * 0.5;
                assert_eq!(p.parse(&t), Ok(ReportUpdate::Translation(expected)));
                let mut r = vec![2u8];
                r.extend(le(&raw));
                assert_eq!(p.parse(&r), Ok(ReportUpdate::Rotation(expected)));
            }
        }
    }

    #[test]
    fn combined_layout_gives_six_axes_with_their_signs() {
        let p = Parser::new(find_model(VENDOR_3DCONNEXION, 0xc635).expect("listed"));
        // Each of the six axes alone, both ways: a swapped or sign-flipped axis shows here.
        for axis in 0..6 {
            for sign in [-1i16, 1] {
                let mut raw = [0i16; 6];
                raw[axis] = sign * 175;
                let mut report = vec![1u8];
                report.extend(le(&raw));
                let mut expected = Axes::default();
                let half = f64::from(sign) * 0.5;
                if axis < 3 {
                    expected.translation[axis] = half;
                } else {
                    expected.rotation[axis - 3] = half;
                }
                assert_eq!(
                    p.parse(&report),
                    Ok(ReportUpdate::SixAxes(expected)),
                    "axis {axis}, sign {sign}"
                );
            }
        }
        let mut report = vec![1u8];
        report.extend(le(&[350, -350, 35, -35, 700, -700]));
        assert_eq!(
            p.parse(&report),
            Ok(ReportUpdate::SixAxes(Axes {
                translation: [1.0, -1.0, 0.1],
                // Beyond the full scale clamps: some units exceed their nominal range.
                rotation: [-0.1, 1.0, -1.0],
            }))
        );
    }

    #[test]
    fn fixture_bytes_of_a_navigator_decode() {
        // A rotation about the second axis and two button reports, as a SpaceNavigator sends them.
        let p = navigator();
        assert_eq!(
            p.parse(&[0x02, 0x00, 0x00, 0xe2, 0xff, 0x00, 0x00]),
            Ok(ReportUpdate::Rotation([0.0, -30.0 / 350.0, 0.0]))
        );
        assert_eq!(p.parse(&[0x03, 0x01, 0x00]), Ok(ReportUpdate::Buttons(1)));
        assert_eq!(p.parse(&[0x03, 0x03, 0x00]), Ok(ReportUpdate::Buttons(3)));
        assert_eq!(
            p.parse(&[0x03, 0x00, 0x00, 0x00, 0x40]),
            Ok(ReportUpdate::Buttons(1 << 30))
        );
    }

    #[test]
    fn short_and_unknown_reports_are_refused_or_ignored() {
        let p = navigator();
        assert_eq!(p.parse(&[]), Err(ReportError::Empty));
        assert_eq!(
            p.parse(&[1, 0, 0, 0]),
            Err(ReportError::Short {
                id: 1,
                len: 4,
                needed: 7
            })
        );
        assert!(matches!(p.parse(&[2, 1]), Err(ReportError::Short { .. })));
        assert!(matches!(p.parse(&[3]), Err(ReportError::Short { .. })));
        assert_eq!(p.parse(&[4, 1]), Ok(ReportUpdate::Ignored(4)));
        assert_eq!(p.parse(&[0x17, 0x55]), Ok(ReportUpdate::Ignored(0x17)));
        // Between the two layouts' lengths: the three axes of the older layout.
        let r = [1, 175, 0, 0, 0, 0, 0, 9, 9, 9];
        assert_eq!(p.parse(&r), Ok(ReportUpdate::Translation([0.5, 0.0, 0.0])));
    }

    #[test]
    fn unknown_products_are_not_models() {
        assert!(find_model(VENDOR_LOGITECH, 0xc52b).is_none());
        assert!(find_model(0x1234, 0xc626).is_none());
        assert!(is_3dconnexion_vendor(0x256f) && !is_3dconnexion_vendor(0x1234));
        // Every listed product is under one of the two vendor ids, once.
        for (i, m) in MODELS.iter().enumerate() {
            assert!(is_3dconnexion_vendor(m.vendor_id), "{m:?}");
            assert!(m.full_scale > 0, "{m:?}");
            assert_eq!(
                MODELS
                    .iter()
                    .position(|o| (o.vendor_id, o.product_id) == (m.vendor_id, m.product_id)),
                Some(i)
            );
        }
    }

    #[test]
    fn puck_state_keeps_what_the_last_reports_said() {
        let p = navigator();
        let mut s = PuckState::default();
        for r in [
            vec![1, 94, 1, 0, 0, 0, 0],
            vec![2, 0, 0, 0, 0, 162, 254],
            vec![3, 2],
        ] {
            s.apply(p.parse(&r).expect("valid"));
        }
        assert_eq!(s.axes.translation, [1.0, 0.0, 0.0]);
        assert_eq!(s.axes.rotation, [0.0, 0.0, -1.0]);
        assert_eq!(s.buttons, 2);
        s.apply(ReportUpdate::Ignored(9));
        assert_eq!(s.buttons, 2);
    }
}

#[cfg(test)]
mod fuzz {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        #[test]
        fn any_bytes_parse_without_panic_to_bounded_axes(bytes in proptest::collection::vec(any::<u8>(), 0..40)) {
            let p = Parser::new(&MODELS[0]);
            if let Ok(u) = p.parse(&bytes) {
                let mut s = PuckState::default();
                s.apply(u);
                for v in s.axes.translation.iter().chain(&s.axes.rotation) {
                    prop_assert!(v.is_finite() && v.abs() <= 1.0);
                }
            }
        }
    }
}
