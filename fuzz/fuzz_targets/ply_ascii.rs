//! The PLY reader on arbitrary bytes, seeded with ascii files (`corpus/ply_ascii`), whole and
//! streamed ([`differential`]). The reader is the same as `ply_binary`'s; the seeds steer the
//! fuzzer to the ascii body.
#![no_main]

#[path = "ply_differential.rs"]
mod differential;

libfuzzer_sys::fuzz_target!(|data: &[u8]| differential::check(data));
