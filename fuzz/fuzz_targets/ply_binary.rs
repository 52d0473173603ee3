//! The PLY reader on arbitrary bytes, seeded with binary files, both endians
//! (`corpus/ply_binary`), whole and streamed ([`differential`]).
#![no_main]

#[path = "ply_differential.rs"]
mod differential;

libfuzzer_sys::fuzz_target!(|data: &[u8]| differential::check(data));
