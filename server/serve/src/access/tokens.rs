//! The roles' tokens: generated from the operating system's random source, read from a token
//! file or the environment, and the lookup of a presented token's role, which hashes it and
//! compares the digest with both roles' in constant time. A token is never shown: [`Token`] has
//! no `Display` and every error here describes a token without quoting it.

use std::fmt;
use std::path::{Path, PathBuf};

use sha2::{Digest, Sha256};
use softhaptic_proto::wire::Role;
use subtle::ConstantTimeEq;

use super::AccessError;

/// The variable holding the instructor's token (with [`OBSERVER_TOKEN_ENV`]).
pub const INSTRUCTOR_TOKEN_ENV: &str = "SOFTHAPTIC_INSTRUCTOR_TOKEN";
/// The variable holding the observer's token (with [`INSTRUCTOR_TOKEN_ENV`]).
pub const OBSERVER_TOKEN_ENV: &str = "SOFTHAPTIC_OBSERVER_TOKEN";
/// The shortest token accepted: 32 characters, as the 128 bits of a generated one in hex.
pub const MIN_TOKEN_CHARS: usize = 32;
/// The longest token accepted (a bound on what a token file can make the server hold).
pub const MAX_TOKEN_CHARS: usize = 512;
/// Bytes drawn from the OS for a generated token: 128 bits.
const GENERATED_TOKEN_BYTES: usize = 16;

/// What is wrong with a token, said without quoting it.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum TokenProblem {
    #[error("the {role} token is empty")]
    Empty { role: &'static str },
    #[error(
        "the {role} token is {chars} characters long; a token needs at least {MIN_TOKEN_CHARS} \
         (e.g. 32 hex digits: `openssl rand -hex 16`)"
    )]
    TooShort { role: &'static str, chars: usize },
    #[error("the {role} token is {chars} characters long; at most {MAX_TOKEN_CHARS} are accepted")]
    TooLong { role: &'static str, chars: usize },
    #[error(
        "the {role} token looks made by hand, not drawn at random: words, years, sequences or \
         repeats make it about {bits} bits to guess, and at least {min} are needed; make one \
         with `openssl rand -hex 16`",
        min = super::strength::MIN_TOKEN_BITS
    )]
    HandMade { role: &'static str, bits: u32 },
    #[error(
        "the {role} token has a character other than a letter, a digit, `-`, `.`, `_` or `~` \
         (it must go into a link unchanged)"
    )]
    Character { role: &'static str },
    #[error("expected `instructor = <token>` or `observer = <token>`")]
    NotAnAssignment,
    #[error("the name before `=` is neither `instructor` nor `observer`")]
    UnknownRole,
    #[error("the {role} token is given a second time (first on line {first_line})")]
    Repeated {
        role: &'static str,
        first_line: usize,
    },
}

/// One role's secret. Never displayed: see the first promise of [`crate::access`]. Its memory is wiped when
/// it is dropped, so a freed token does not linger for a core dump or a later allocation.
#[derive(Clone, PartialEq, Eq)]
pub struct Token(zeroize::Zeroizing<String>);

impl fmt::Debug for Token {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str("Token(<redacted>)")
    }
}

impl Token {
    /// 128 bits from the operating system's random source, as 32 lowercase hex digits.
    pub fn generate() -> Result<Token, AccessError> {
        let mut bytes = [0u8; GENERATED_TOKEN_BYTES];
        getrandom::fill(&mut bytes).map_err(|e| AccessError::Random(e.to_string()))?;
        let mut text = String::with_capacity(2 * GENERATED_TOKEN_BYTES);
        for b in bytes {
            text.push(hex_digit(b >> 4));
            text.push(hex_digit(b & 0x0f));
        }
        Ok(Token(zeroize::Zeroizing::new(text)))
    }

    /// A token given by a person (file, variable) for `role`: at least [`MIN_TOKEN_CHARS`]
    /// characters, each one that goes into a URL unchanged (RFC 3986's unreserved set), so the
    /// printed link works as printed.
    pub fn parse(text: &str, role: Role) -> Result<Token, TokenProblem> {
        let role = role.as_str();
        let chars = text.chars().count();
        if chars == 0 {
            return Err(TokenProblem::Empty { role });
        }
        if !text
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || matches!(b, b'-' | b'.' | b'_' | b'~'))
        {
            return Err(TokenProblem::Character { role });
        }
        if chars < MIN_TOKEN_CHARS {
            return Err(TokenProblem::TooShort { role, chars });
        }
        if chars > MAX_TOKEN_CHARS {
            return Err(TokenProblem::TooLong { role, chars });
        }
        // Length alone does not make a secret: `aaaa…`, `abab…` or
        // `instructor-token-for-lab-2024xyz` pass it (see `strength`).
        let bits = super::strength::estimated_bits(text);
        if bits < super::strength::MIN_TOKEN_BITS {
            return Err(TokenProblem::HandMade {
                role,
                bits: bits as u32,
            });
        }
        Ok(Token(zeroize::Zeroizing::new(text.to_owned())))
    }

    /// The secret itself, for the one place that must show it: the links printed at start.
    pub fn expose_secret(&self) -> &str {
        &self.0
    }

    fn digest(&self) -> [u8; 32] {
        Sha256::digest(self.0.as_bytes()).into()
    }
}

fn hex_digit(nibble: u8) -> char {
    char::from(b"0123456789abcdef"[usize::from(nibble & 0x0f)])
}

/// Where the tokens came from (logged; the tokens themselves never are).
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum TokenSource {
    File(PathBuf),
    Environment,
    Generated,
}

impl fmt::Display for TokenSource {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            TokenSource::File(path) => write!(f, "token file {}", path.display()),
            TokenSource::Environment => {
                write!(f, "{INSTRUCTOR_TOKEN_ENV} and {OBSERVER_TOKEN_ENV}")
            }
            TokenSource::Generated => f.write_str("generated at start (--tokens)"),
        }
    }
}

/// The two roles' tokens.
#[derive(Clone)]
pub struct Tokens {
    instructor: Token,
    observer: Token,
    /// SHA-256 of each token, what presented tokens are compared with (see [`crate::access`]).
    instructor_digest: [u8; 32],
    observer_digest: [u8; 32],
    source: TokenSource,
}

impl fmt::Debug for Tokens {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Tokens")
            .field("source", &self.source)
            .finish_non_exhaustive()
    }
}

impl Tokens {
    /// Both roles' tokens; refused when they are the same (the observer's link would then
    /// control the replay).
    pub fn new(
        instructor: Token,
        observer: Token,
        source: TokenSource,
    ) -> Result<Self, AccessError> {
        if instructor == observer {
            return Err(AccessError::SameTokens {
                source_name: source.to_string(),
            });
        }
        Ok(Self {
            instructor_digest: instructor.digest(),
            observer_digest: observer.digest(),
            instructor,
            observer,
            source,
        })
    }

    /// Two fresh tokens from the OS's random source (`--tokens`).
    pub fn generate() -> Result<Self, AccessError> {
        Self::new(
            Token::generate()?,
            Token::generate()?,
            TokenSource::Generated,
        )
    }

    /// The role whose token `presented` is, in constant time: both digests are always compared,
    /// and only then is the answer looked at.
    pub fn role_of(&self, presented: &str) -> Option<Role> {
        let digest: [u8; 32] = Sha256::digest(presented.as_bytes()).into();
        let instructor = digest.ct_eq(&self.instructor_digest);
        let observer = digest.ct_eq(&self.observer_digest);
        if bool::from(instructor) {
            Some(Role::Instructor)
        } else if bool::from(observer) {
            Some(Role::Observer)
        } else {
            None
        }
    }

    pub fn instructor(&self) -> &Token {
        &self.instructor
    }

    pub fn observer(&self) -> &Token {
        &self.observer
    }

    pub fn source(&self) -> &TokenSource {
        &self.source
    }
}

/// Reads a token file: `instructor = <token>` and `observer = <token>`, one per line; blank
/// lines and lines starting with `#` are skipped. Errors name the file and the line.
pub fn read_token_file(path: &Path) -> Result<Tokens, AccessError> {
    // Bounded (a token file is a few lines), and wiped once parsed.
    let text = crate::files::read_text(path, crate::files::FileKind::Secrets)
        .map(zeroize::Zeroizing::new)
        .map_err(|source| AccessError::TokenFileRead {
            path: path.to_path_buf(),
            source,
        })?;
    // A token file others may read gives their links away: said once, at start.
    crate::files::warn_if_others_may_read(path, "the token file");
    parse_token_file(path, &text)
}

fn parse_token_file(path: &Path, text: &str) -> Result<Tokens, AccessError> {
    let line_error = |line: usize, problem: TokenProblem| AccessError::TokenFileLine {
        path: path.to_path_buf(),
        line,
        problem,
    };
    let mut instructor: Option<(Token, usize)> = None;
    let mut observer: Option<(Token, usize)> = None;
    for (index, raw) in text.lines().enumerate() {
        let line = index + 1;
        let content = raw.trim();
        if content.is_empty() || content.starts_with('#') {
            continue;
        }
        let Some((name, value)) = content.split_once('=') else {
            return Err(line_error(line, TokenProblem::NotAnAssignment));
        };
        let (role, slot) = match name.trim() {
            "instructor" => (Role::Instructor, &mut instructor),
            "observer" => (Role::Observer, &mut observer),
            _ => return Err(line_error(line, TokenProblem::UnknownRole)),
        };
        if let Some((_, first_line)) = slot {
            return Err(line_error(
                line,
                TokenProblem::Repeated {
                    role: role.as_str(),
                    first_line: *first_line,
                },
            ));
        }
        let token = Token::parse(value.trim(), role).map_err(|p| line_error(line, p))?;
        *slot = Some((token, line));
    }
    let missing = |role: &'static str| AccessError::TokenFileMissing {
        path: path.to_path_buf(),
        role,
    };
    let (instructor, _) = instructor.ok_or_else(|| missing("instructor"))?;
    let (observer, _) = observer.ok_or_else(|| missing("observer"))?;
    Tokens::new(instructor, observer, TokenSource::File(path.to_path_buf()))
}

/// The tokens of [`INSTRUCTOR_TOKEN_ENV`] and [`OBSERVER_TOKEN_ENV`] as `env` gives them; `None`
/// when neither is set (an empty variable counts as unset).
pub(super) fn tokens_from_environment(
    env: &dyn Fn(&str) -> Option<String>,
) -> Result<Option<Tokens>, AccessError> {
    let read = |name: &str| env(name).filter(|v| !v.is_empty());
    match (read(INSTRUCTOR_TOKEN_ENV), read(OBSERVER_TOKEN_ENV)) {
        (None, None) => Ok(None),
        (Some(_), None) => Err(AccessError::OneTokenVariable {
            set: INSTRUCTOR_TOKEN_ENV,
            unset: OBSERVER_TOKEN_ENV,
        }),
        (None, Some(_)) => Err(AccessError::OneTokenVariable {
            set: OBSERVER_TOKEN_ENV,
            unset: INSTRUCTOR_TOKEN_ENV,
        }),
        (Some(i), Some(o)) => {
            let parse = |text: &str, role, name| {
                Token::parse(text.trim(), role)
                    .map_err(|problem| AccessError::TokenVariable { name, problem })
            };
            let instructor = parse(&i, Role::Instructor, INSTRUCTOR_TOKEN_ENV)?;
            let observer = parse(&o, Role::Observer, OBSERVER_TOKEN_ENV)?;
            Tokens::new(instructor, observer, TokenSource::Environment).map(Some)
        }
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported
mod tests {
    use super::*;
    use crate::access::AccessConfig;
    use crate::access::testing::{I, O, tokens};
    use std::sync::Arc;

    #[test]
    fn generated_tokens_are_32_lowercase_hex_digits_and_differ() {
        let a = Token::generate().unwrap();
        let b = Token::generate().unwrap();
        for t in [&a, &b] {
            assert_eq!(t.expose_secret().len(), 32);
            assert!(
                t.expose_secret()
                    .bytes()
                    .all(|c| c.is_ascii_digit() || (b'a'..=b'f').contains(&c))
            );
        }
        assert_ne!(a, b);
        // Strong by the same measure as a person's: a generated token passes it.
        for t in [&a, &b] {
            Token::parse(t.expose_secret(), Role::Instructor).unwrap();
        }
        let both = Tokens::generate().unwrap();
        assert_ne!(both.instructor(), both.observer());
    }

    #[test]
    fn each_token_gives_its_role_and_anything_else_none() {
        let t = tokens();
        assert_eq!(t.role_of(I), Some(Role::Instructor));
        assert_eq!(t.role_of(O), Some(Role::Observer));
        for wrong in [
            "",
            "0123456789abcdef0123456789abcdee",
            &I[..31],
            &format!("{I}0"),
        ] {
            assert_eq!(t.role_of(wrong), None, "{wrong:?}");
        }
    }

    #[test]
    fn nothing_that_debug_prints_shows_a_token() {
        let t = tokens();
        let shown = format!(
            "{t:?} {:?} {:?} {:?}",
            t.instructor(),
            AccessConfig {
                tokens: Some(Arc::new(t.clone())),
                ..AccessConfig::default()
            },
            Token::generate().unwrap()
        );
        assert!(!shown.contains(I) && !shown.contains(O), "{shown}");
    }

    #[test]
    fn a_token_file_is_read_within_a_bound_and_only_from_a_regular_file() {
        let dir = tempfile::tempdir().unwrap();
        let good = dir.path().join("tokens");
        std::fs::write(&good, format!("instructor = {I}\nobserver = {O}\n")).unwrap();
        assert_eq!(
            read_token_file(&good).unwrap().role_of(O),
            Some(Role::Observer)
        );
        // A device that never ends, a directory, a file far larger than a few lines of tokens:
        // refused by name, without reading them whole.
        let huge = dir.path().join("huge");
        std::fs::write(&huge, vec![b'#'; 100 << 10]).unwrap();
        for (path, expected) in [
            (Path::new("/dev/zero"), "not a regular file"),
            (dir.path(), "not a regular file"),
            (huge.as_path(), "a token or credentials file may be"),
        ] {
            let e = read_token_file(path).err().unwrap().to_string();
            assert!(e.contains(&path.display().to_string()), "{e}");
            assert!(e.contains(expected), "{e}");
        }
    }

    #[test]
    fn a_token_file_is_read_and_its_errors_name_file_line_and_problem_without_the_token() {
        let path = Path::new("/lab/tokens.txt");
        let good = format!("# the lab's links\n\ninstructor = {I}\n  observer={O}  \n");
        let t = parse_token_file(path, &good).unwrap();
        assert_eq!(t.role_of(I), Some(Role::Instructor));
        assert_eq!(t.role_of(O), Some(Role::Observer));
        assert_eq!(t.source(), &TokenSource::File(path.to_path_buf()));

        let short = "0123456789abcdef";
        let cases = [
            (
                format!("instructor = {short}\nobserver = {O}\n"),
                "/lab/tokens.txt:1: the instructor token is 16 characters long; a token needs at least 32",
            ),
            (
                format!("instructor = {I}\n{O}\n"),
                "/lab/tokens.txt:2: expected `instructor = <token>`",
            ),
            (
                format!("instructor = {I}\nobserver = {}\n", "ab".repeat(20)),
                "/lab/tokens.txt:2: the observer token looks made by hand",
            ),
            (
                format!("instructor = instructor-token-for-lab-2024xyz\nobserver = {O}\n"),
                "/lab/tokens.txt:1: the instructor token looks made by hand, not drawn at random: \
                 words, years, sequences or repeats make it about 70 bits to guess, and at least \
                 80 are needed",
            ),
            (
                format!("instructor = {I}\ntrainee = {O}\n"),
                "/lab/tokens.txt:2: the name before `=` is neither",
            ),
            (
                format!("instructor = {I}\ninstructor = {O}\n"),
                "/lab/tokens.txt:2: the instructor token is given a second time (first on line 1)",
            ),
            (
                format!("instructor = {I}\n"),
                "/lab/tokens.txt: no `observer = <token>` line",
            ),
            (
                format!("instructor = {I}\nobserver = {I}\n"),
                "the instructor and observer tokens are the same",
            ),
            (
                format!("instructor = {I}\nobserver = {O}#x\n"),
                "/lab/tokens.txt:2: the observer token has a character other than",
            ),
            (
                "instructor =\nobserver = x\n".to_owned(),
                "/lab/tokens.txt:1: the instructor token is empty",
            ),
        ];
        for (text, expected) in cases {
            let err = parse_token_file(path, &text).unwrap_err().to_string();
            assert!(
                err.starts_with(expected) || err.contains(expected),
                "{err}\nexpected: {expected}"
            );
            for secret in [I, O, short, "instructor-token"] {
                assert!(!err.contains(secret), "the error shows a token: {err}");
            }
        }
    }
}
