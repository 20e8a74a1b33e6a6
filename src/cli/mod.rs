//! The command line's own pieces beside `main.rs`: how the library's named choices become
//! clap's possible values.

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
