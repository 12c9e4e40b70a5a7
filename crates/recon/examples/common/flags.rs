//! Command-line flags of the recon examples, read word by word: the examples take a handful
//! of `--flag value` pairs and positional words, too few to pull in an argument parser, but
//! each flag's value must be parsed with an error that names the flag.
#![allow(dead_code)]

use std::fmt::Display;
use std::str::FromStr;

/// The words after the program name, read one flag at a time.
pub struct Flags {
    words: std::iter::Skip<std::env::Args>,
}

impl Flags {
    /// The process's own arguments.
    pub fn from_env() -> Self {
        Self { words: std::env::args().skip(1) }
    }

    /// The next word: a flag, or a positional word.
    pub fn next_flag(&mut self) -> Option<String> {
        self.words.next()
    }

    /// The word after `flag`, parsed; the error names the flag.
    pub fn value<T: FromStr>(&mut self, flag: &str) -> Result<T, String>
    where
        T::Err: Display,
    {
        let word = self.words.next().ok_or_else(|| format!("{flag} needs a value"))?;
        word.parse().map_err(|e| format!("{flag}: {e}"))
    }

    /// The `WxH` image size after `flag`.
    pub fn size(&mut self, flag: &str) -> Result<(u32, u32), String> {
        let v: String = self.value(flag)?;
        let (w, h) = v.split_once('x').ok_or_else(|| format!("{flag} {v}: expected WxH"))?;
        Ok((w.parse().map_err(|e| format!("{flag}: {e}"))?, h.parse().map_err(|e| format!("{flag}: {e}"))?))
    }
}
