//! Options picked by name: the library's option enums (precision, formula, acceleration,
//! compression, …) list their values, names and descriptions here, once, for every front
//! end. The command line builds its possible values and `--help` from [`Choice::CHOICES`];
//! Python parses its keyword strings with [`Choice::parse`]. The library itself never
//! names a flag or a keyword: an [`UnknownChoice`] says what was given and what is known,
//! and each front end puts its own spelling of the option in front.
//!
//! An enum becomes a choice through [`choice_enum!`](crate::choice_enum): its variants are written
//! `Variant = "name"`, their doc comments become the descriptions, `default Variant`
//! after the enum's name gives its `Default`, and `Display` and `FromStr` use the names.

use std::fmt;

/// One value of a [`Choice`]: the value, the name a user types, and its doc comment.
#[derive(Clone, Copy, Debug)]
pub struct Named<T: 'static> {
    /// The value.
    pub value: T,
    /// Its name on the command line and in Python.
    pub name: &'static str,
    /// Its doc comment, lines as written (each with a trailing newline).
    pub doc: &'static str,
}

impl<T> Named<T> {
    /// The first paragraph of the doc comment on one line, without its final full stop:
    /// what a list of possible values shows beside the name.
    pub fn summary(&self) -> String {
        let lines: Vec<&str> = self
            .doc
            .lines()
            .map(str::trim)
            .take_while(|l| !l.is_empty())
            .collect();
        let joined = lines.join(" ");
        joined.strip_suffix('.').unwrap_or(&joined).to_string()
    }
}

/// An option enum whose values are picked by name.
pub trait Choice: Copy + PartialEq + Sized + 'static {
    /// Every value in the order front ends list them, with its name and description.
    const CHOICES: &'static [Named<Self>];

    /// The name of `self`.
    fn choice_name(self) -> &'static str {
        Self::CHOICES
            .iter()
            .find(|c| c.value == self)
            .map_or("", |c| c.name)
    }

    /// The value named `name` (exactly as listed).
    fn parse(name: &str) -> Result<Self, UnknownChoice> {
        Self::CHOICES
            .iter()
            .find(|c| c.name == name)
            .map(|c| c.value)
            .ok_or_else(|| UnknownChoice {
                given: name.to_string(),
                known: Self::CHOICES.iter().map(|c| c.name).collect(),
            })
    }
}

/// A name that is not one of a [`Choice`]'s: what was given and the names known, for the
/// front end to say under its own spelling of the option.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct UnknownChoice {
    /// The name given.
    pub given: String,
    /// The names known, in order.
    pub known: Vec<&'static str>,
}

impl fmt::Display for UnknownChoice {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "unknown value {:?}: expected one of {}",
            self.given,
            self.known.join(", ")
        )
    }
}

impl std::error::Error for UnknownChoice {}

/// Declare an option enum whose values are picked by name (see the module docs):
///
/// ```
/// cylaov::choice_enum! {
///     /// How loud.
///     #[derive(Clone, Copy, Debug, PartialEq, Eq)]
///     pub enum Volume default Low {
///         /// Barely heard.
///         Low = "low",
///         /// Heard across the room.
///         High = "high",
///     }
/// }
/// use cylaov::choice::Choice;
/// assert_eq!("high".parse::<Volume>(), Ok(Volume::High));
/// assert_eq!(Volume::default().choice_name(), "low");
/// assert_eq!(Volume::CHOICES[1].summary(), "Heard across the room");
/// ```
#[macro_export]
macro_rules! choice_enum {
    (
        $(#[$meta:meta])*
        $vis:vis enum $ty:ident $(default $default:ident)? {
            $(
                $(#[doc = $doc:literal])*
                $variant:ident = $name:literal
            ),* $(,)?
        }
    ) => {
        $(#[$meta])*
        $vis enum $ty {
            $( $(#[doc = $doc])* $variant, )*
        }

        impl $crate::choice::Choice for $ty {
            const CHOICES: &'static [$crate::choice::Named<Self>] = &[
                $( $crate::choice::Named {
                    value: $ty::$variant,
                    name: $name,
                    doc: concat!($($doc, "\n",)*),
                }, )*
            ];
        }

        impl ::std::fmt::Display for $ty {
            fn fmt(&self, f: &mut ::std::fmt::Formatter<'_>) -> ::std::fmt::Result {
                f.write_str(<Self as $crate::choice::Choice>::choice_name(*self))
            }
        }

        impl ::std::str::FromStr for $ty {
            type Err = $crate::choice::UnknownChoice;
            fn from_str(s: &str) -> Result<Self, Self::Err> {
                <Self as $crate::choice::Choice>::parse(s)
            }
        }

        $(
            impl Default for $ty {
                fn default() -> Self {
                    $ty::$default
                }
            }
        )?
    };
}

#[cfg(test)]
mod tests {
    use super::*;

    crate::choice_enum! {
        /// Test enum.
        #[derive(Clone, Copy, Debug, PartialEq, Eq)]
        enum Two default B {
            /// First line
            /// continued.
            ///
            /// Second paragraph.
            A = "a-one",
            B = "b",
        }
    }

    /// Names, descriptions (first paragraph, one line, no full stop), defaults and the
    /// refusal that lists what is known.
    #[test]
    fn names_docs_and_defaults() {
        assert_eq!(Two::default(), Two::B);
        assert_eq!(Two::A.choice_name(), "a-one");
        assert_eq!(Two::CHOICES[0].summary(), "First line continued");
        assert_eq!(Two::CHOICES[1].summary(), "");
        assert_eq!("b".parse::<Two>(), Ok(Two::B));
        let e = "A-ONE".parse::<Two>().unwrap_err();
        assert_eq!(e.known, ["a-one", "b"]);
        assert_eq!(
            e.to_string(),
            "unknown value \"A-ONE\": expected one of a-one, b"
        );
    }
}
