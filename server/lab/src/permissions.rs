//! What each party of the lab may do on NATS, as a `nats-server` `authorization` block: the
//! one place the lab's permissions are written, used by `softhaptic nats-config` to make a
//! lab's configuration and by the tests' real `nats-server`.
//!
//! A station's credentials publish its own subjects and nothing else: its heartbeat, its frames,
//! and its own archive bucket (the object store's messages and the JetStream requests naming
//! that bucket's stream alone); they subscribe to the hubs' requests to it and to its own inbox.
//! So a station cannot speak for another, read another's frames or the hub's replies, or write,
//! purge or read another's recordings. A hub's credentials read: every station's heartbeat,
//! frames, stats, exercise, marks and inclusions, requests to stations for their scene and meshes, and JetStream's read-only
//! requests (stream and consumer info, messages, ordered consumers) on any stream, and JetStream's
//! advisories of streams made and deleted (the archive's listing follows the buckets); they publish
//! no frame, no heartbeat and nothing into any bucket. Replies to a request it received are
//! allowed to everyone (`allow_responses`): that is how a station answers a hub and a client
//! answers JetStream's flow control.
//!
//! Inboxes are per party ([`crate::Party::inbox_prefix`]): `_INBOX.station.NAME.>` and
//! `_INBOX.hub.>`, each subscribable by its owner alone.

use std::fmt::Write as _;

use super::archive::{bucket, bucket_stream};
use super::{Party, Subjects};

/// The subjects a party may publish and subscribe to.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Permissions {
    pub publish: Vec<String>,
    pub subscribe: Vec<String>,
}

/// What `party` may do.
pub fn of(party: Party<'_>) -> Permissions {
    match party {
        Party::Station(name) => station(name),
        Party::Hub => hub(),
    }
}

fn station(name: &str) -> Permissions {
    let subjects = Subjects::of(name);
    let stream = bucket_stream(name);
    let publish = vec![
        subjects.status,
        format!("softhaptic.station.{name}.>"),
        // The bucket's messages: parts (`C`) and metas (`M`).
        format!("$O.{}.>", bucket(name)),
        "$JS.API.INFO".to_owned(),
        // Its bucket's stream: INFO, CREATE, UPDATE, DELETE, PURGE; MSG.GET and MSG.DELETE.
        format!("$JS.API.STREAM.*.{stream}"),
        format!("$JS.API.STREAM.MSG.*.{stream}"),
        format!("$JS.API.DIRECT.GET.{stream}"),
        format!("$JS.API.DIRECT.GET.{stream}.>"),
        // Consumers on it (the uploads' read-back, the object store's readers): CREATE, NAMES,
        // LIST; CREATE with a name, INFO, DELETE; DURABLE.CREATE; MSG.NEXT.
        format!("$JS.API.CONSUMER.*.{stream}"),
        format!("$JS.API.CONSUMER.*.{stream}.>"),
        format!("$JS.API.CONSUMER.DURABLE.CREATE.{stream}.>"),
        format!("$JS.API.CONSUMER.MSG.NEXT.{stream}.>"),
    ];
    let subscribe = vec![
        subjects.session,
        subjects.mesh,
        subjects.action,
        format!("{}.>", Party::Station(name).inbox_prefix()),
    ];
    Permissions { publish, subscribe }
}

fn hub() -> Permissions {
    let publish = [
        // Requests to any station for its scene and its meshes, and instructors' actions.
        "softhaptic.station.*.session",
        "softhaptic.station.*.mesh",
        "softhaptic.station.*.action",
        // JetStream, read only.
        "$JS.API.INFO",
        "$JS.API.STREAM.NAMES",
        "$JS.API.STREAM.LIST",
        "$JS.API.STREAM.INFO.*",
        "$JS.API.STREAM.MSG.GET.*",
        "$JS.API.DIRECT.GET.*",
        "$JS.API.DIRECT.GET.*.>",
        "$JS.API.CONSUMER.CREATE.*",
        "$JS.API.CONSUMER.CREATE.*.>",
        "$JS.API.CONSUMER.INFO.*.*",
        "$JS.API.CONSUMER.DELETE.*.*",
        "$JS.API.CONSUMER.MSG.NEXT.*.*",
    ];
    let subscribe = [
        super::STATUS_SUBJECTS.to_owned(),
        "softhaptic.station.*.contact".to_owned(),
        "softhaptic.station.*.stats".to_owned(),
        "softhaptic.station.*.exercise".to_owned(),
        "softhaptic.station.*.marks".to_owned(),
        "softhaptic.station.*.inclusions".to_owned(),
        // Buckets made and deleted, for the archive's listing (`crate::listing`).
        super::listing::STREAM_CREATED.to_owned(),
        super::listing::STREAM_DELETED.to_owned(),
        format!("{}.>", Party::Hub.inbox_prefix()),
    ];
    Permissions {
        publish: publish.map(str::to_owned).to_vec(),
        subscribe: subscribe.to_vec(),
    }
}

/// A member of the lab and the public key (`U…`) of the nkey it signs in with.
#[derive(Debug, Clone)]
pub struct Member<'a> {
    pub party: Party<'a>,
    pub public_key: String,
}

/// The `authorization` block of a `nats-server` configuration for `members` (include it in the
/// server's configuration, or give it alone with `-c`).
pub fn authorization_config(members: &[Member<'_>]) -> String {
    let list = |subjects: &[String]| {
        subjects
            .iter()
            .map(|s| format!("\"{s}\""))
            .collect::<Vec<_>>()
            .join(", ")
    };
    let mut out = String::from(
        "# The softhaptic lab's NATS users (made by `softhaptic nats-config`): each station\n\
         # publishes only its own subjects and archive bucket, hubs only read.\n\
         authorization {\n  users = [\n",
    );
    for member in members {
        let p = of(member.party);
        let who = match member.party {
            Party::Station(name) => format!("station {name}"),
            Party::Hub => "the hubs".to_owned(),
        };
        let _ = write!(
            out,
            "    # {who}\n    {{\n      nkey: \"{}\"\n      permissions: {{\n        \
             publish: {{ allow: [{}] }}\n        subscribe: {{ allow: [{}] }}\n        \
             allow_responses: true\n      }}\n    }}\n",
            member.public_key,
            list(&p.publish),
            list(&p.subscribe),
        );
    }
    out.push_str("  ]\n}\n");
    out
}

/// The file of the authorization block in a directory made by [`write_lab_config`].
pub const AUTHORIZATION_FILE: &str = "authorization.conf";
/// The hubs' seed file in such a directory (every hub of the lab uses it).
pub const HUB_SEED_FILE: &str = "hub.nk";

/// A station's seed file in such a directory.
pub fn station_seed_file(name: &str) -> String {
    format!("station-{name}.nk")
}

/// What [`write_lab_config`] wrote.
#[derive(Debug)]
pub struct LabConfig {
    pub authorization: std::path::PathBuf,
    /// Each party's seed file, stations first, with whether it was made now (else kept).
    pub seeds: Vec<(String, std::path::PathBuf, bool)>,
}

/// Writes a lab's NATS sign-in into `dir` (made, mode 0700, if missing): one user nkey seed
/// per station and one for the hubs (mode 0600, the form `--nats-credentials` reads; a seed
/// already there is kept, so adding a station does not change the others' keys) and
/// [`AUTHORIZATION_FILE`] listing their public keys with [`of`]'s permissions. Errors name the
/// file; no seed is ever in one.
pub fn write_lab_config(dir: &std::path::Path, stations: &[String]) -> Result<LabConfig, String> {
    use std::os::unix::fs::DirBuilderExt;
    for name in stations {
        super::check_station_name(name)?;
    }
    std::fs::DirBuilder::new()
        .recursive(true)
        .mode(0o700)
        .create(dir)
        .map_err(|e| format!("{}: {e}", dir.display()))?;
    let mut parties: Vec<(String, Party<'_>)> = stations
        .iter()
        .map(|n| (station_seed_file(n), Party::Station(n)))
        .collect();
    parties.push((HUB_SEED_FILE.to_owned(), Party::Hub));
    let mut members = Vec::new();
    let mut seeds = Vec::new();
    for (file, party) in parties {
        let path = dir.join(&file);
        let (key, made) = seed_in(&path, party)?;
        members.push(Member {
            party,
            public_key: key.public_key(),
        });
        let who = match party {
            Party::Station(name) => format!("station {name}"),
            Party::Hub => "hub".to_owned(),
        };
        seeds.push((who, path, made));
    }
    let authorization = dir.join(AUTHORIZATION_FILE);
    std::fs::write(&authorization, authorization_config(&members))
        .map_err(|e| format!("{}: {e}", authorization.display()))?;
    Ok(LabConfig {
        authorization,
        seeds,
    })
}

/// The user nkey in the seed file `path`, made (mode 0600) when there is none; and whether it
/// was made now.
fn seed_in(path: &std::path::Path, party: Party<'_>) -> Result<(nkeys::KeyPair, bool), String> {
    use std::io::Write as _;
    use std::os::unix::fs::OpenOptionsExt;
    let shown = || path.display().to_string();
    match crate::files::read_text(path, crate::files::FileKind::Secrets) {
        Ok(text) => {
            let text = zeroize::Zeroizing::new(text);
            let seed = text
                .lines()
                .map(str::trim)
                .find(|l| l.starts_with("SU"))
                .ok_or_else(|| format!("{}: no user nkey seed (SU…) in it", shown()))?;
            let key = nkeys::KeyPair::from_seed(seed)
                .map_err(|_| format!("{}: the seed does not decode", shown()))?;
            Ok((key, false))
        }
        Err(crate::files::ReadError::Io(e)) if e.kind() == std::io::ErrorKind::NotFound => {
            let key = nkeys::KeyPair::new_user();
            let seed = zeroize::Zeroizing::new(
                key.seed()
                    .map_err(|e| format!("{}: making a seed: {e}", shown()))?,
            );
            let mut file = std::fs::OpenOptions::new()
                .write(true)
                .create_new(true)
                .mode(0o600)
                .open(path)
                .map_err(|e| format!("{}: {e}", shown()))?;
            let text = zeroize::Zeroizing::new(format!(
                "# softhaptic lab: the NATS sign-in of the {}; keep it secret\n{}\n",
                match party {
                    Party::Station(name) => format!("station {name}"),
                    Party::Hub => "hubs".to_owned(),
                },
                seed.as_str()
            ));
            file.write_all(text.as_bytes())
                .map_err(|e| format!("{}: {e}", shown()))?;
            Ok((key, true))
        }
        Err(e) => Err(format!("{}: {e}", shown())),
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
mod tests {
    use super::*;

    /// Whether NATS's subject `pattern` (`*` one token, `>` the rest) matches `subject`.
    fn matches(pattern: &str, subject: &str) -> bool {
        let mut p = pattern.split('.');
        let mut s = subject.split('.');
        loop {
            match (p.next(), s.next()) {
                (Some(">"), Some(_)) => return true,
                (Some("*"), Some(_)) => {}
                (Some(a), Some(b)) if a == b => {}
                (None, None) => return true,
                _ => return false,
            }
        }
    }

    fn may(list: &[String], subject: &str) -> bool {
        list.iter().any(|p| matches(p, subject))
    }

    #[test]
    fn a_station_publishes_only_its_own_and_a_hub_publishes_no_frame() {
        let desk1 = of(Party::Station("desk-1"));
        for own in [
            "softhaptic.stations.desk-1",
            "softhaptic.station.desk-1.contact",
            "$O.softhaptic-sessions-desk-1.C.abc",
            "$JS.API.STREAM.PURGE.OBJ_softhaptic-sessions-desk-1",
            "$JS.API.CONSUMER.MSG.NEXT.OBJ_softhaptic-sessions-desk-1.c",
        ] {
            assert!(may(&desk1.publish, own), "{own}");
        }
        for other in [
            "softhaptic.stations.desk-2",
            "softhaptic.station.desk-2.contact",
            "$O.softhaptic-sessions-desk-2.M.x",
            "$JS.API.STREAM.PURGE.OBJ_softhaptic-sessions-desk-2",
            "$JS.API.STREAM.MSG.GET.OBJ_softhaptic-sessions-desk-2",
            "$JS.API.STREAM.NAMES",
            "$JS.API.CONSUMER.CREATE.OBJ_softhaptic-sessions-desk-2",
        ] {
            assert!(!may(&desk1.publish, other), "{other}");
        }
        for other in [
            "softhaptic.station.desk-2.contact",
            "_INBOX.hub.x.y",
            "_INBOX.station.desk-2.x",
        ] {
            assert!(!may(&desk1.subscribe, other), "{other}");
        }
        let hub = of(Party::Hub);
        for read in [
            "$JS.API.STREAM.INFO.OBJ_softhaptic-sessions-desk-1",
            "$JS.API.STREAM.MSG.GET.OBJ_softhaptic-sessions-desk-1",
            "softhaptic.station.desk-1.session",
        ] {
            assert!(may(&hub.publish, read), "{read}");
        }
        for write in [
            "softhaptic.station.desk-1.contact",
            "softhaptic.station.desk-1.stats",
            "softhaptic.stations.desk-1",
            "$O.softhaptic-sessions-desk-1.C.abc",
            "$JS.API.STREAM.PURGE.OBJ_softhaptic-sessions-desk-1",
            "$JS.API.STREAM.DELETE.OBJ_softhaptic-sessions-desk-1",
            "$JS.API.STREAM.MSG.DELETE.OBJ_softhaptic-sessions-desk-1",
        ] {
            assert!(!may(&hub.publish, write), "{write}");
        }
    }

    #[test]
    fn nats_config_makes_private_seeds_keeps_them_on_a_second_run_and_refuses_a_bad_name() {
        use std::os::unix::fs::PermissionsExt;
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("lab-nats");
        let read = |p: &std::path::Path| {
            crate::files::read_text(p, crate::files::FileKind::Secrets).unwrap()
        };
        let first = write_lab_config(&out, &["desk-1".to_owned()]).unwrap();
        assert!(first.seeds.iter().all(|(_, _, made)| *made), "{first:?}");
        let mode = |p: &std::path::Path| std::fs::metadata(p).unwrap().permissions().mode() & 0o777;
        assert_eq!(mode(&out), 0o700);
        for (_, path, _) in &first.seeds {
            assert_eq!(mode(path), 0o600, "{}", path.display());
        }
        let seed = read(&out.join(station_seed_file("desk-1")));
        let config = read(&first.authorization);
        // Public keys only: no seed in the server's configuration.
        let seed_line = seed.lines().find(|l| l.starts_with("SU")).unwrap();
        assert!(!config.contains(seed_line), "{config}");
        assert!(config.contains(&nkeys::KeyPair::from_seed(seed_line).unwrap().public_key()));
        // Adding a station keeps desk-1's key and the hubs'.
        let second = write_lab_config(&out, &["desk-1".to_owned(), "desk-2".to_owned()]).unwrap();
        let made: Vec<bool> = second.seeds.iter().map(|(_, _, made)| *made).collect();
        assert_eq!(made, [false, true, false]);
        assert_eq!(read(&out.join(station_seed_file("desk-1"))), seed);
        let again = read(&second.authorization);
        for line in config.lines().filter(|l| l.contains("nkey:")) {
            assert!(again.contains(line), "{line} lost");
        }
        let e = write_lab_config(&out, &["desk.1".to_owned()]).unwrap_err();
        assert!(e.contains("\"desk.1\""), "{e}");
    }

    #[test]
    fn the_configuration_lists_each_member_with_its_key() {
        let text = authorization_config(&[
            Member {
                party: Party::Station("desk-1"),
                public_key: "UDESK1".into(),
            },
            Member {
                party: Party::Hub,
                public_key: "UHUB".into(),
            },
        ]);
        assert!(text.contains("nkey: \"UDESK1\""), "{text}");
        assert!(text.contains("\"softhaptic.station.desk-1.>\""), "{text}");
        assert!(text.contains("nkey: \"UHUB\""), "{text}");
        assert_eq!(text.matches("allow_responses: true").count(), 2);
    }
}
