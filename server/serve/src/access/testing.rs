//! Two roles' tokens and an [`Access`] for the unit tests of the access rules.

#![allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported

use std::sync::Arc;

use softhaptic_proto::wire::Role;

use super::{Access, AccessConfig, Token, TokenSource, Tokens};

pub(super) const I: &str = "820282620bb7debb2b6fb8f77ac1644a";
pub(super) const O: &str = "d5b629ee48797979cfda037291bd83dc";

/// The instructor's token is [`I`], the observer's [`O`].
pub(super) fn tokens() -> Tokens {
    Tokens::new(
        Token::parse(I, Role::Instructor).unwrap(),
        Token::parse(O, Role::Observer).unwrap(),
        TokenSource::Environment,
    )
    .unwrap()
}

/// The rules of `config`, with no viewer page to hash.
pub(super) fn access(config: AccessConfig) -> Arc<Access> {
    Arc::new(Access::new(config, ""))
}
