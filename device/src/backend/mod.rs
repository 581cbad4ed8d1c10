//! What every vendor's device backend shares: how its library is found and loaded
//! ([`library`]), how its frame and units map into the world and which limits it runs with
//! ([`mapping`]), and when a lost device is reconnected and how long to wait ([`reconnect`]).
//! The backends ([`crate::openhaptics`], [`crate::forcedimension`]) keep only what their vendor's
//! API makes different.

pub mod library;
pub mod mapping;
pub mod reconnect;
