//! ABB RAPID modules (`.mod`, `.modx`) as text: parse them ([`parse`]), read the literal
//! `robtarget`, `tooldata` and `wobjdata` values ([`data`]), the configuration data of the
//! controller's kinematics ([`conf`]) and rewrite numbers in place ([`rewrite`]), every byte
//! not rewritten kept. Pure: no I/O.

pub mod conf;
pub mod correct;
pub mod data;
pub mod lex;
pub mod parse;
pub mod program;
pub mod rewrite;

pub use parse::{Decl, Module, MoveUse, Value, parse};

/// A module that does not parse, with the line (from 1) where it went wrong.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("line {line}: {message}")]
pub struct RapidError {
    /// Line, from 1.
    pub line: usize,
    /// What is wrong there.
    pub message: String,
}

impl RapidError {
    /// An error at `line`.
    pub fn new(line: usize, message: impl Into<String>) -> Self {
        Self {
            line,
            message: message.into(),
        }
    }
}

#[cfg(test)]
mod tests;
