//! Strict reading of scene JSON: what `serde_json` accepts by default but a scene file must
//! not be, each refused with a message a person can act on.
//!
//! - A struct written as a positional array (`[camera, cylinders]`): serde's derive accepts
//!   it, so a typo'd scene could render. Scene structs read through [`object`] (maps only).
//! - A vector with the wrong number of elements: the default message for `[0, 0, 0, 0]` is
//!   "trailing characters"; [`vec3`] says "must have 3 numbers, got 4".
//! - Very long numbers and strings echoed back in a message ([`shorten`]).

use serde::de::{self, Deserialize, Deserializer, IgnoredAny, MapAccess, SeqAccess, Visitor};
use std::fmt;
use std::marker::PhantomData;

/// Deserialize `T` from a JSON object only (never from an array of its fields in order).
pub fn object<'de, D, T>(d: D) -> Result<T, D::Error>
where
    D: Deserializer<'de>,
    T: Deserialize<'de>,
{
    struct ObjectOnly<T>(PhantomData<T>);
    impl<'de, T: Deserialize<'de>> Visitor<'de> for ObjectOnly<T> {
        type Value = T;
        fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
            f.write_str("a JSON object {\"name\": value, ...}")
        }
        fn visit_map<A: MapAccess<'de>>(self, map: A) -> Result<T, A::Error> {
            T::deserialize(de::value::MapAccessDeserializer::new(map))
        }
    }
    d.deserialize_map(ObjectOnly(PhantomData))
}

/// A wrapper that reads its content with [`object`].
pub struct Object<T>(pub T);

impl<'de, T: Deserialize<'de>> Deserialize<'de> for Object<T> {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        object(d).map(Object)
    }
}

/// A list whose every element is read with [`object`].
pub fn objects<'de, D, T>(d: D) -> Result<Vec<T>, D::Error>
where
    D: Deserializer<'de>,
    T: Deserialize<'de>,
{
    let v: Vec<Object<T>> = Vec::deserialize(d)?;
    Ok(v.into_iter().map(|o| o.0).collect())
}

/// An optional [`object`] (a field with `#[serde(default)]`).
pub fn opt_object<'de, D, T>(d: D) -> Result<Option<T>, D::Error>
where
    D: Deserializer<'de>,
    T: Deserialize<'de>,
{
    Ok(Option::<Object<T>>::deserialize(d)?.map(|o| o.0))
}

/// An optional list of [`object`]s.
pub fn opt_objects<'de, D, T>(d: D) -> Result<Option<Vec<T>>, D::Error>
where
    D: Deserializer<'de>,
    T: Deserialize<'de>,
{
    Ok(Option::<Vec<Object<T>>>::deserialize(d)?.map(|v| v.into_iter().map(|o| o.0).collect()))
}

/// A list of [`object`]s, or one object of another kind `R` in its place (a scene's
/// `"cylinders": {"file": ...}`, `"cameras": {"orbit": ...}`).
#[derive(Clone, Debug)]
pub enum ListOr<T, R> {
    /// The list, every element read with [`object`].
    List(Vec<T>),
    /// The object.
    Object(R),
}

impl<'de, T: Deserialize<'de>, R: Deserialize<'de>> Deserialize<'de> for ListOr<T, R> {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct V<T, R>(PhantomData<(T, R)>);
        impl<'de, T: Deserialize<'de>, R: Deserialize<'de>> Visitor<'de> for V<T, R> {
            type Value = ListOr<T, R>;
            fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
                f.write_str("a list [{...}, ...] or an object {...}")
            }
            fn visit_seq<A: SeqAccess<'de>>(self, seq: A) -> Result<Self::Value, A::Error> {
                let v: Vec<Object<T>> =
                    Vec::deserialize(de::value::SeqAccessDeserializer::new(seq))?;
                Ok(ListOr::List(v.into_iter().map(|o| o.0).collect()))
            }
            fn visit_map<A: MapAccess<'de>>(self, map: A) -> Result<Self::Value, A::Error> {
                R::deserialize(de::value::MapAccessDeserializer::new(map)).map(ListOr::Object)
            }
        }
        d.deserialize_any(V(PhantomData))
    }
}

/// Exactly three numbers; the message counts what was there.
pub fn vec3<'de, D: Deserializer<'de>>(d: D) -> Result<[f64; 3], D::Error> {
    struct Three;
    impl<'de> Visitor<'de> for Three {
        type Value = [f64; 3];
        fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
            f.write_str("an array of 3 numbers [x, y, z]")
        }
        fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<[f64; 3], A::Error> {
            let mut v = [0.0; 3];
            let mut n = 0usize;
            while n < 3 {
                match seq.next_element::<f64>()? {
                    Some(x) => v[n] = x,
                    None => break,
                }
                n += 1;
            }
            while seq.next_element::<IgnoredAny>()?.is_some() {
                n += 1;
            }
            if n != 3 {
                return Err(de::Error::custom(format!(
                    "must have 3 numbers [x, y, z], got {n}"
                )));
            }
            Ok(v)
        }
    }
    d.deserialize_seq(Three)
}

/// [`vec3`] for an optional field (`null` or absent is `None`).
pub fn opt_vec3<'de, D: Deserializer<'de>>(d: D) -> Result<Option<[f64; 3]>, D::Error> {
    #[derive(serde::Deserialize)]
    struct V(#[serde(deserialize_with = "vec3")] [f64; 3]);
    Ok(Option::<V>::deserialize(d)?.map(|v| v.0))
}

/// A message with every run of more than 40 digits or letters (of any script: a name of
/// 10 000 `é` or `木` floods as well) cut to its first 20 and last 8 characters with the
/// count between, so a 600-digit number does not flood the
/// terminal: `10000000000000000000…(572 more)…00000000`.
pub fn shorten(message: &str) -> String {
    const KEEP_HEAD: usize = 20;
    const KEEP_TAIL: usize = 8;
    let mut out = String::with_capacity(message.len().min(400));
    let chars: Vec<char> = message.chars().collect();
    let mut i = 0;
    while i < chars.len() {
        let mut j = i;
        while j < chars.len() && (chars[j].is_alphanumeric() || chars[j] == '.') {
            j += 1;
        }
        if j == i {
            out.push(chars[i]);
            i += 1;
            continue;
        }
        let run = j - i;
        if run > 40 {
            out.extend(&chars[i..i + KEEP_HEAD]);
            out.push_str(&format!("…({} more)…", run - KEEP_HEAD - KEEP_TAIL));
            out.extend(&chars[j - KEEP_TAIL..j]);
        } else {
            out.extend(&chars[i..j]);
        }
        i = j;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shorten_cuts_only_long_runs() {
        assert_eq!(shorten("got -1 at line 3"), "got -1 at line 3");
        let long = format!("got {} here", "9".repeat(600));
        let s = shorten(&long);
        assert_eq!(
            s,
            format!("got {}…(572 more)…{} here", "9".repeat(20), "9".repeat(8))
        );
        let name = format!("name {:?}", "木".repeat(100));
        assert_eq!(
            shorten(&name),
            format!("name \"{}…(72 more)…{}\"", "木".repeat(20), "木".repeat(8))
        );
    }
}
