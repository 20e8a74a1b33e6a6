//! The command line beside `main.rs`: each command's arguments (clap derives) and the
//! function that turns them into the library's options and calls it, one file a command;
//! [`common`] holds what several share; here, how the library's named choices become
//! clap's possible values, and how an error is reported.

pub mod batch;
pub mod bench;
pub mod cameras;
pub mod common;
pub mod compare;
pub mod export_mitsuba;
pub mod generate;
pub mod import;
pub mod render;
pub mod scan;
pub mod stress;
pub mod verify;

use clap::builder::{PossibleValue, PossibleValuesParser, TypedValueParser};
use cylaov::choice::Choice;

/// The value parser of an option whose values are a library [`Choice`]: the names as
/// clap's possible values (listed by `--help` with each value's description, and by the
/// error for an unknown one), parsed into the enum.
pub fn choice<T: Choice + Clone + Send + Sync>() -> impl TypedValueParser<Value = T> {
    let values = T::CHOICES.iter().map(|c| {
        let summary = c.summary();
        let value = PossibleValue::new(c.name);
        if summary.is_empty() {
            value
        } else {
            value.help(summary)
        }
    });
    // Only listed names reach the map: clap refused every other first.
    PossibleValuesParser::new(values).try_map(|name| T::parse(&name))
}

/// The exit status of a check (`compare`, `verify`): its own status once its text is
/// printed, else 2 (the check could not be made; the error is reported here).
pub fn check_status(outcome: anyhow::Result<(String, u8)>) -> std::process::ExitCode {
    let printed = outcome.and_then(|(text, code)| {
        common::say(&text)?;
        Ok(code)
    });
    match printed {
        Ok(code) => std::process::ExitCode::from(code),
        Err(e) => {
            report(&e);
            std::process::ExitCode::from(2)
        }
    }
}

/// Print an error as the one `error: ...` line every command ends with on failure.
pub fn report(e: &anyhow::Error) {
    cylaov::output::console::warn(&format!("error: {e:#}"));
}
