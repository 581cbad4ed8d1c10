//! The shared test vectors the Rust and JavaScript sides both check (proto/WIRE.md, "Shared
//! test vectors"): one message of every type the viewer must decode, the frames it must refuse,
//! and the files `softhaptic vectors write` puts under `proto/vectors/`.

use serde::{Deserialize, Serialize};

use super::*;

/// One entry of `proto/vectors/messages.json`: a message the viewer must decode (`json`), or raw
/// text it must refuse (`raw`, `valid: false`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum MessageVector {
    Valid {
        name: String,
        json: serde_json::Value,
    },
    Invalid {
        name: String,
        raw: String,
        valid: bool,
    },
}

/// The shared message vectors: every message type (a contact with every flag, one without any),
/// an unknown type, and malformed frames. Deterministic, so the written file can be checked.
pub fn message_vectors() -> Result<Vec<MessageVector>, serde_json::Error> {
    let hello = ServerMessage::Hello(Hello {
        protocol_version: PROTOCOL_VERSION,
        session_id: "3f2a9c1e".into(),
        role: Role::Instructor,
        mode: Mode::Live,
        server: "softhaptic 0.1.0".into(),
        force_feedback: true,
        accepts_marks: true,
    });
    let tool = ToolShape::Sphere { radius_m: 0.01 };
    let material = Material::PAPER_SOFT;
    let scene = |tool: ToolShape, model: &str, spec: ModelSpec, limits: ValidityLimits| {
        let calibration =
            CalibrationTable::half_space(tool, material, crate::calibration::PAPER_THRESHOLD_M)
                .map_err(serde::ser::Error::custom)?;
        Ok::<_, serde_json::Error>(ServerMessage::Scene(Box::new(SceneMessage {
            protocol_version: PROTOCOL_VERSION,
            tool,
            material,
            model: ModelInfo {
                name: model.into(),
                valid_depth_m: limits.valid_depth_m,
                valid_inclination_rad: limits.valid_inclination_rad,
            },
            contact_model: ContactModelInfo::new(&tool, &spec, &limits),
            calibration,
            render_profile: RenderProfile::Paper,
            render_meshes: vec![RenderMeshInfo {
                name: "liver".into(),
                url: "/meshes/liver.bin".into(),
                vertex_count: 120_000,
                object_in_world: Pose {
                    position_m: DVec3::new(0.0, 0.0, 0.0),
                    orientation: glam::DQuat::from_rotation_y(0.5),
                },
            }],
            device: DeviceInfo {
                name: "simulated PHANTOM Desktop".into(),
                force_feedback: true,
                peak_force_n: 7.9,
                continuous_force_n: 1.75,
                max_stiffness_n_per_m: 1000.0,
                damping_n_s_per_m: 5.0,
                workspace_radius_m: 0.1,
            },
            guide: None,
        })))
    };
    let pressing = ContactState {
        tick: 12_345,
        time_ns: 12_345_000_000,
        tip_in_world: Pose {
            position_m: DVec3::new(0.01, 0.047, -0.002),
            orientation: glam::DQuat::from_rotation_z(0.2),
        },
        tip_velocity_m_s: DVec3::new(0.0, -0.01, 0.0),
        buttons: 1,
        in_contact: true,
        depth_m: 0.003,
        normal: DVec3::new(0.0, 1.0, 0.0),
        contact_point_m: DVec3::new(0.01, 0.05, -0.002),
        contact_radius_m: (0.01f64 * 0.003).sqrt(),
        force_n: DVec3::new(0.0, 1.2, 0.0),
        flags: ContactFlags::BEYOND_VALID_DEPTH | ContactFlags::RAMPING,
        guide: None,
    };
    // Guided along an expert's path: pulled 0.4 N toward where the expert's tool was.
    let guided = ContactState {
        guide: Some(crate::GuideState {
            force_n: DVec3::new(0.25, 0.0, -0.3125),
            target_m: DVec3::new(0.0116, 0.047, -0.004),
            progress: 0.375,
            gain: 0.75,
            effective_gain: 0.5,
            engaged: true,
            pass: 0,
        }),
        ..pressing
    };
    let all_flags = ContactState {
        flags: ContactFlags::all(),
        ..pressing
    };
    let free = ContactState {
        tick: 42,
        time_ns: 42_000_000,
        ..ContactState::IDLE
    };
    let stats = ServerMessage::Stats(StatsMessage {
        loop_rate_hz: 999.8,
        period_error_us: PeriodErrorUs {
            p50: 3.5,
            p99: 21.0,
            p999: 48.25,
            max: 130.0,
        },
        overruns: 2,
        standby_ticks: 5,
        compute_us: ComputeUs {
            p50: 12.5,
            p99: 40.0,
            max: 95.0,
        },
        viewers: 3,
        dropped_frames: 17,
        device: DeviceStatus::Disconnected,
    });
    let valid = [
        ("hello", hello),
        (
            "scene_sphere",
            scene(
                tool,
                "hertz",
                ModelSpec {
                    exact_sphere: true,
                    curvature: true,
                    hyperelastic: true,
                    ..ModelSpec::PAPER
                },
                ValidityLimits {
                    valid_depth_m: 0.0058,
                    valid_inclination_rad: 22f64.to_radians(),
                    source: "sphere R = 6 mm, block 100 × 100 × 30 mm, neo-Hookean FEM (inclination: paper)"
                        .into(),
                },
            )?,
        ),
        (
            "scene_cone",
            scene(
                ToolShape::Cone {
                    half_angle_rad: std::f64::consts::FRAC_PI_4,
                    radius_m: 0.01,
                },
                "sneddon_cone",
                ModelSpec {
                    curvature: true,
                    inclination: true,
                    ..ModelSpec::PAPER
                },
                ValidityLimits::paper(&ToolShape::Cone {
                    half_angle_rad: std::f64::consts::FRAC_PI_4,
                    radius_m: 0.01,
                }),
            )?,
        ),
        ("scene_guided", {
            let mut m = scene(tool, "hertz", ModelSpec::PAPER, ValidityLimits::paper(&tool))?;
            if let ServerMessage::Scene(s) = &mut m {
                s.guide = Some(crate::guide::GuidePathInfo {
                    source: "expert-slide.mcap".into(),
                    path_m: vec![
                        DVec3::new(-0.01, 0.05, 0.0),
                        DVec3::new(0.0, 0.049, 0.0),
                        DVec3::new(0.01, 0.05, 0.0),
                    ],
                    length_m: 0.02,
                    max_force_n: 1.5,
                    gain: crate::GuideGain::AS_NEEDED,
                });
            }
            m
        }),
        (
            "scene_paper_layer",
            scene(
                tool,
                "hertz",
                ModelSpec {
                    thickness: Some(crate::model::LayerSpec {
                        thickness_m: 0.03,
                        bonded: true,
                    }),
                    ..ModelSpec::PAPER
                },
                ValidityLimits::paper(&tool),
            )?,
        ),
        (
            "contact_pressing",
            ServerMessage::Contact(ContactFrame::from_state(&pressing, 7, 0.0146, 0)),
        ),
        (
            "contact_every_flag",
            ServerMessage::Contact(ContactFrame::from_state(&all_flags, 8, 0.0146, 3)),
        ),
        (
            "contact_guided",
            ServerMessage::Contact(ContactFrame::from_state(&guided, 10, 0.0146, 0)),
        ),
        (
            "contact_over_inclusion",
            ServerMessage::Contact(ContactFrame {
                inclusion_force_ratio: Some(1.8),
                ..ContactFrame::from_state(&pressing, 11, 0.0146, 0)
            }),
        ),
        (
            "contact_free",
            ServerMessage::Contact(ContactFrame::from_state(&free, 9, 0.0, 0)),
        ),
        ("stats", stats),
        (
            "mark",
            ServerMessage::Mark(MarkMessage {
                id: 2,
                time_ns: 4_250_000_000,
                note: "too fast on the approach".into(),
                point_m: Some([-0.0297, 0.0681, 0.0068]),
            }),
        ),
        (
            "metrics",
            ServerMessage::Metrics(MetricsMessage {
                peak_force_n: 2.35,
                peak_force_time_s: 12.5,
                safe_force_n: 2.0,
                time_above_safe_s: 0.42,
                time_in_contact_s: 18.25,
                path_length_in_contact_m: 0.0375,
                mean_squared_jerk_m2_s6: 812.5,
                pushes: 4,
                device_fault_ticks: 0,
                flags_raised: [("ramping".to_owned(), 1), ("stiffness_capped".to_owned(), 3)]
                    .into_iter()
                    .collect(),
                ticks: 30000,
                is_final: false,
            }),
        ),
        (
            "hello_observer",
            ServerMessage::Hello(Hello {
                protocol_version: PROTOCOL_VERSION,
                session_id: "3f2a9c1e".into(),
                role: Role::Observer,
                mode: Mode::Live,
                server: "softhaptic 0.1.0".into(),
                // An observer of a desk with a SpaceMouse: the force is not felt.
                force_feedback: false,
                accepts_marks: true,
            }),
        ),
        ("exercise_running", exercise_vector(false)),
        ("exercise_ended", exercise_vector(true)),
        (
            "inclusions_revealed",
            ServerMessage::Inclusions(InclusionsMessage {
                revealed: true,
                exercise_index: Some(0),
                attempt: Some(1),
                inclusions: vec![InclusionView {
                    centre_m: [0.012, 0.031, -0.004],
                    radius_m: 0.005,
                    stiffness_ratio: 4.0,
                    centre_depth_m: 0.008,
                }],
            }),
        ),
        ("dashboard", dashboard_vector()),
        (
            "action_result",
            ServerMessage::ActionResult(ActionResult {
                station: "desk-3".into(),
                action: "rearm_device".into(),
                done: false,
                reason: Some("the device's force output is not latched off".into()),
            }),
        ),
        (
            "refused_replay_control",
            ServerMessage::Refused(Refused {
                request: "replay_control".into(),
                reason: "an observer cannot control the replay: only an instructor's link can"
                    .into(),
            }),
        ),
    ];
    let mut out = Vec::new();
    for (name, message) in valid {
        out.push(MessageVector::Valid {
            name: name.into(),
            json: serde_json::to_value(&message)?,
        });
    }
    // A scene from a server that predates `contact_model` and `render_profile` (and its
    // recordings): still valid, read as the paper's law with the paper's limits, drawn with the
    // paper's profile.
    if let Some(MessageVector::Valid { json, .. }) = out.get(1) {
        let mut old = json.clone();
        if let Some(fields) = old.as_object_mut() {
            fields.remove("contact_model");
            fields.remove("render_profile");
            fields.insert(
                "model".into(),
                serde_json::json!({
                    "name": "hertz",
                    "valid_depth_m": crate::model::PAPER_VALID_DEPTH_M,
                    "valid_inclination_rad": crate::model::paper_valid_inclination_rad(&tool),
                }),
            );
        }
        out.push(MessageVector::Valid {
            name: "scene_before_contact_model".into(),
            json: old,
        });
    }
    let invalid = [
        ("not_json", "contact seq=1"),
        ("not_an_object", "[1, 2, 3]"),
        ("no_type", r#"{"seq": 1}"#),
        ("type_not_a_string", r#"{"type": 5}"#),
        (
            "contact_missing_fields",
            r#"{"type":"contact","seq":1,"tick":1}"#,
        ),
        (
            "contact_unknown_flag",
            r#"{"type":"contact","seq":1,"tick":1,"time_ns":1000000,"tip_in_world":{"position_m":[0,0,0],"orientation":[0,0,0,1]},"in_contact":false,"depth_m":0,"normal":[0,1,0],"contact_point_m":[0,0,0],"contact_radius_m":0,"deformed_radius_m":0,"force_n":[0,0,0],"flags":["on_fire"],"dropped":0}"#,
        ),
        (
            "contact_depth_is_text",
            r#"{"type":"contact","seq":1,"tick":1,"time_ns":1000000,"tip_in_world":{"position_m":[0,0,0],"orientation":[0,0,0,1]},"in_contact":true,"depth_m":"deep","normal":[0,1,0],"contact_point_m":[0,0,0],"contact_radius_m":0,"deformed_radius_m":0,"force_n":[0,0,0],"flags":[],"dropped":0}"#,
        ),
    ];
    for (name, raw) in invalid {
        out.push(MessageVector::Invalid {
            name: name.into(),
            raw: raw.into(),
            valid: false,
        });
    }
    // A replay server's hello and status, and the controls a viewer sends it (the viewer's
    // encoder must produce exactly these).
    let replay = [
        (
            "hello_replay",
            serde_json::to_value(ServerMessage::Hello(Hello {
                protocol_version: PROTOCOL_VERSION,
                session_id: "19abc0de123-4242".into(),
                role: Role::Instructor,
                mode: Mode::Replay,
                server: "softhaptic 0.1.0".into(),
                force_feedback: true,
                accepts_marks: true,
            }))?,
        ),
        (
            "replay_status",
            serde_json::to_value(ServerMessage::Replay(ReplayStatus {
                duration_s: 2.98,
                time_s: 1.25,
                paused: false,
                speed: 0.5,
                file: "sphere-press.mcap".into(),
                gaps: Vec::new(),
                above_safe: Vec::new(),
                marks: Vec::new(),
            }))?,
        ),
        (
            "replay_status_with_gaps",
            serde_json::to_value(ServerMessage::Replay(ReplayStatus {
                duration_s: 12.5,
                time_s: 0.0,
                paused: true,
                speed: 1.0,
                file: "lab-station-3.mcap".into(),
                gaps: vec![
                    ReplayGap {
                        start_s: 3.25,
                        end_s: 3.272,
                        ticks: 22,
                        cause: GapCause::LostTicks,
                    },
                    ReplayGap {
                        start_s: 7.0,
                        end_s: 8.0,
                        ticks: 1000,
                        cause: GapCause::Damaged,
                    },
                ],
                above_safe: vec![ReplaySpan {
                    start_s: 5.5,
                    end_s: 5.81,
                }],
                marks: vec![ReplayMark {
                    id: 1,
                    time_s: 2.25,
                    note: "too fast on the approach".into(),
                }],
            }))?,
        ),
    ];
    for (name, json) in replay {
        out.push(MessageVector::Valid {
            name: name.into(),
            json,
        });
    }
    let controls = [
        ("replay_control_pause", ReplayAction::Pause, None, None),
        (
            "replay_control_play_at_2x",
            ReplayAction::Play,
            None,
            Some(2.0),
        ),
        ("replay_control_seek", ReplayAction::Seek, Some(1.5), None),
    ];
    for (name, action, time_s, speed) in controls {
        out.push(MessageVector::Valid {
            name: name.into(),
            json: serde_json::to_value(ReplayControl {
                action,
                time_s,
                speed,
            })?,
        });
    }
    // The first message of a viewer to a server with tokens (the viewer's encoder must produce
    // exactly this).
    out.push(MessageVector::Valid {
        name: "auth".into(),
        json: serde_json::to_value(Auth {
            token: "0123456789abcdef0123456789abcdef".into(),
        })?,
    });
    // An instructor's mark, as the viewer's encoder writes it.
    out.push(MessageVector::Valid {
        name: "add_mark".into(),
        json: serde_json::to_value(MarkRequest {
            note: "too fast on the approach".into(),
            point_m: Some([-0.0297, 0.0681, 0.0068]),
        })?,
    });
    // An instructor starting the next exercise, as the viewer's encoder writes it.
    out.push(MessageVector::Valid {
        name: "exercise_control".into(),
        json: serde_json::to_value(ExerciseControl {
            action: ExerciseAction::Next,
        })?,
    });
    // An instructor's actions from a hub's dashboard, as the page's encoder writes them.
    for (name, action) in [
        (
            "station_action_acknowledge",
            StationAction::Acknowledge { alert: 2 },
        ),
        (
            "station_action_exercise",
            StationAction::Exercise {
                control: ExerciseAction::Repeat,
            },
        ),
        (
            "station_action_mark",
            StationAction::Mark {
                note: "check the grip".into(),
            },
        ),
        ("station_action_rearm", StationAction::RearmDevice),
    ] {
        out.push(MessageVector::Valid {
            name: name.into(),
            json: serde_json::to_value(StationActionRequest {
                station: "desk-3".into(),
                action,
            })?,
        });
    }
    // Well-formed but of a type no viewer knows: to be ignored and counted, not refused.
    out.push(MessageVector::Valid {
        name: "unknown_type".into(),
        json: serde_json::json!({"type": "telemetry_v2", "payload": [1, 2, 3]}),
    });
    Ok(out)
}

/// The shared test-vector files, as (file name under `proto/vectors/`, contents). Written by
/// `softhaptic vectors write`, read by the viewer's tests, and compared with these contents by a
/// test of this crate so that the files cannot drift from the code.
pub fn vector_files() -> Result<Vec<(&'static str, String)>, serde_json::Error> {
    let deformation = serde_json::to_string_pretty(&crate::deformation::deformation_vectors())?;
    let surface = serde_json::to_string_pretty(&crate::deformation::surface_profile_vectors())?;
    let messages = serde_json::to_string_pretty(&message_vectors()?)?;
    Ok(vec![
        ("deformation.json", deformation + "\n"),
        ("surface_profile.json", surface + "\n"),
        ("messages.json", messages + "\n"),
    ])
}

/// An `exercise` message of a press exercise: running (1.5 s into its 20 s), or ended with its
/// result (passed, the hold complete at 4.2 s).
fn exercise_vector(ended: bool) -> ServerMessage {
    use crate::exercise::{
        AttemptEnd, AttemptResult, Exercise, ExpertSpread, PassMark, PressTask, Score, Task,
    };
    let exercise = Exercise {
        name: "Press and hold 2 N".into(),
        instructions: "Press the marked site with 2 N and hold it for 3 s.".into(),
        time_limit_s: 20.0,
        task: Task::Press(PressTask {
            site_m: [0.0, 0.03, 0.0],
            normal: [0.0, 1.0, 0.0],
            site_radius_m: 0.005,
            target_force_n: 2.0,
            tolerance_n: 0.3,
            hold_s: 3.0,
            safe_force_n: 4.0,
        }),
        pass: vec![PassMark {
            metric: "hold_force_sd_n".into(),
            at_least: None,
            at_most: Some(0.15),
            experts: Some(ExpertSpread {
                recordings: 5,
                mean: 0.08,
                sd: 0.03,
                min: 0.05,
                max: 0.12,
            }),
        }],
    };
    let start_ns = 2_000_000_000;
    let result = ended.then(|| {
        let score = Score {
            completed: true,
            safe: true,
            metrics: [
                ("hold_force_sd_n", 0.0625),
                ("hold_s", 3.0),
                ("peak_force_n", 2.25),
                ("time_above_safe_s", 0.0),
                ("time_to_hold_s", 4.25),
            ]
            .into_iter()
            .map(|(k, v)| (k.to_owned(), v))
            .collect(),
        };
        AttemptResult::judge(
            &exercise,
            "ana",
            1,
            (start_ns, start_ns + 4_250_000_000),
            AttemptEnd::Completed,
            score,
        )
    });
    ServerMessage::Exercise(Box::new(ExerciseMessage {
        trainee: "ana".into(),
        index: 0,
        count: 2,
        attempt: 1,
        state: if ended {
            ExerciseState::Ended
        } else {
            ExerciseState::Running
        },
        exercise,
        time_ns: if ended {
            start_ns + 4_250_000_000
        } else {
            start_ns + 1_500_000_000
        },
        remaining_s: if ended { 0.0 } else { 18.5 },
        result,
        next_in_s: ended.then_some(10.0),
        exercise_file: None,
        exercise_toml: None,
    }))
}

/// A hub's dashboard of two stations: one in trouble (an alert not acknowledged, one
/// acknowledged), one offline without a summary.
fn dashboard_vector() -> ServerMessage {
    let alert = |id, kind, detail: &str, acknowledged| Alert {
        id,
        kind,
        time_ns: 4_250_000_000 + u64::from(id) * 1_000_000_000,
        unix_ms: 1_796_000_000_000 + u64::from(id) * 1000,
        detail: detail.into(),
        acknowledged,
    };
    ServerMessage::Dashboard(Box::new(DashboardMessage {
        time_unix_ms: 1_796_000_010_000,
        stations: vec![
            DashboardStation {
                name: "desk-1".into(),
                scene: "liver, sphere 10 mm, simulated device".into(),
                state: "live".into(),
                viewers: 1,
                hub_viewers: 2,
                summary: Some(StationSummary {
                    trainee: Some("ana".into()),
                    exercise: Some(ExerciseSummary {
                        name: "Press and hold 2 N".into(),
                        index: 0,
                        count: 2,
                        attempt: 1,
                        state: ExerciseState::Running,
                        remaining_s: 12.5,
                        passed: None,
                    }),
                    in_contact: true,
                    force_n: vec![1.5, 1.75, 2.25, 2.5, 2.0],
                    safe_force_n: 2.0,
                    peak_force_n: 2.5,
                    time_above_safe_s: 0.75,
                    time_in_contact_s: 6.5,
                    pushes: 3,
                    device: DeviceSummary {
                        state: DeviceStatus::Ok,
                        fault_ticks: 0,
                        lost_ticks: 1,
                        motors_warm: false,
                    },
                    alerts: vec![
                        alert(
                            1,
                            AlertKind::AboveSafeForce,
                            "2.5 N, above the safe 2.0 N",
                            Some(Acknowledgement {
                                by: "instructor at 127.0.0.1:50412 on a hub".into(),
                                unix_ms: 1_796_000_004_000,
                            }),
                        ),
                        alert(2, AlertKind::DeviceFault, "device disconnected", None),
                    ],
                }),
            },
            DashboardStation {
                name: "desk-2".into(),
                scene: "liver, cone 10 mm, simulated device".into(),
                state: "offline".into(),
                viewers: 0,
                hub_viewers: 0,
                summary: None,
            },
        ],
    }))
}
