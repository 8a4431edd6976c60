//! PSNRs in JSON (the strict evaluation's saved seeds and results.json): an exact match
//! (or nothing to compare) scores infinity, which JSON has no number for, so it is
//! written as the text "inf" and read back as infinity. Used as
//! `#[serde(with = "decibels")]` on `[f64; 3]` and `Option<[f64; 3]>` fields.

use serde::{Deserialize, Deserializer, Serialize, Serializer};

#[derive(Serialize, Deserialize)]
#[serde(untagged)]
enum Db {
    Number(f64),
    Text(String),
}

impl From<f64> for Db {
    fn from(v: f64) -> Db {
        if v.is_finite() {
            Db::Number(v)
        } else {
            Db::Text(v.to_string())
        }
    }
}

impl Db {
    fn value<E: serde::de::Error>(self) -> Result<f64, E> {
        match self {
            Db::Number(v) => Ok(v),
            Db::Text(t) => t
                .parse()
                .map_err(|_| E::custom(format!("{t:?} is not a number of decibels"))),
        }
    }
}

/// `[f64; 3]` and `Option<[f64; 3]>`.
pub trait Decibels: Sized {
    fn put<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error>;
    fn get<'de, D: Deserializer<'de>>(d: D) -> Result<Self, D::Error>;
}

impl Decibels for [f64; 3] {
    fn put<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        self.map(Db::from).serialize(s)
    }
    fn get<'de, D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let [a, b, c] = <[Db; 3]>::deserialize(d)?;
        Ok([a.value()?, b.value()?, c.value()?])
    }
}

impl Decibels for Option<[f64; 3]> {
    fn put<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        self.map(|v| v.map(Db::from)).serialize(s)
    }
    fn get<'de, D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        match Option::<[Db; 3]>::deserialize(d)? {
            None => Ok(None),
            Some([a, b, c]) => Ok(Some([a.value()?, b.value()?, c.value()?])),
        }
    }
}

pub fn serialize<T: Decibels, S: Serializer>(v: &T, s: S) -> Result<S::Ok, S::Error> {
    v.put(s)
}

pub fn deserialize<'de, T: Decibels, D: Deserializer<'de>>(d: D) -> Result<T, D::Error> {
    T::get(d)
}
