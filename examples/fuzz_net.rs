//! A bounded mutation fuzzer for the command protocol that runs on the stable
//! toolchain (the libFuzzer target in `fuzz/` needs nightly). It starts from a corpus
//! of good datagrams, signed and unsigned, mutates them byte- and word-wise, keeps the
//! mutants that still parse as new seeds, and runs every input through the same
//! oracle as the libFuzzer target (`adrive::net::fuzzing::exercise`), which panics on a
//! broken invariant. See `fuzz/README.md`.
//!
//! ```text
//! cargo run --release --example fuzz_net -- --iterations 1000000 --seed 7
//! ```

use adrive::net::auth::Auth;
use adrive::net::fuzzing::{exercise, FUZZ_KEY};
use adrive::net::proto::{BadDatagramCounts, MAX_DATAGRAM};
use clap::Parser;
use std::panic;
use std::process::ExitCode;
use std::time::Instant;

#[derive(Parser)]
#[command(about = "Fuzz the adrive command protocol parser and authentication")]
struct Args {
    /// Inputs to try.
    #[arg(long, default_value_t = 100_000)]
    iterations: u64,
    /// Random seed; the same seed replays the same run.
    #[arg(long, default_value_t = 1)]
    seed: u64,
}

/// SplitMix64: small, seedable, good enough to pick mutations.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }

    fn below(&mut self, n: usize) -> usize {
        (self.next() % n.max(1) as u64) as usize
    }
}

fn seeds() -> Vec<Vec<u8>> {
    let auth = Auth::from_key_bytes(FUZZ_KEY).expect("fuzz key is long enough");
    let mut seeds: Vec<Vec<u8>> = [
        "steer 0.2\n",
        "engage\ntrans drive\n",
        "seq 17\r\nsteer -0.25\r\ngas 0.3  # gentle\r\n",
        "accel -0.5",
        "disengage\n",
        "brake 1\ntrans p\ngas 0\n",
        "# comment\n\n\tSTEER\t1\n",
    ]
    .iter()
    .map(|s| s.as_bytes().to_vec())
    .collect();
    for (body, seq) in [
        ("steer 0.2\ngas 0.1\n", 1001),
        ("engage\r\nbrake 0.5\r\n", 1),
    ] {
        seeds.push(auth.sign(body, seq).into_bytes());
    }
    seeds
}

fn mutate(rng: &mut Rng, pool: &[Vec<u8>], out: &mut Vec<u8>) {
    out.clear();
    out.extend_from_slice(&pool[rng.below(pool.len())]);
    for _ in 0..=rng.below(4) {
        let len = out.len();
        match rng.below(9) {
            0 if len > 0 => {
                let i = rng.below(len);
                out[i] ^= 1 << rng.below(8);
            }
            1 if len > 0 => {
                let i = rng.below(len);
                out[i] = rng.next() as u8;
            }
            2 => {
                let i = rng.below(len + 1);
                out.insert(i, rng.next() as u8);
            }
            3 if len > 0 => {
                let i = rng.below(len);
                let j = (i + 1 + rng.below(8)).min(len);
                out.drain(i..j);
            }
            4 if len > 0 => {
                let i = rng.below(len);
                let j = (i + 1 + rng.below(16)).min(len);
                let chunk = out[i..j].to_vec();
                let at = rng.below(out.len() + 1);
                out.splice(at..at, chunk);
            }
            5 | 6 => {
                let word = adrive::net::fuzzing::DICTIONARY
                    [rng.below(adrive::net::fuzzing::DICTIONARY.len())]
                .as_bytes();
                let at = rng.below(len + 1);
                out.splice(at..at, word.iter().copied());
            }
            7 => {
                let other = &pool[rng.below(pool.len())];
                out.extend_from_slice(other);
            }
            _ => out.truncate(rng.below(len + 1)),
        }
    }
    if rng.below(1000) == 0 {
        // Now and then, straddle the size limit.
        out.resize(MAX_DATAGRAM + rng.below(3) - 1, b' ');
    }
}

fn main() -> ExitCode {
    let args = Args::parse();
    let mut rng = Rng(args.seed);
    let mut pool = seeds();
    let counts = BadDatagramCounts::new();
    let mut accepted = 0u64;
    let mut input = Vec::with_capacity(2 * MAX_DATAGRAM);
    let started = Instant::now();

    // Seeds must pass: a failure here is a broken oracle, not a finding.
    for seed in &pool {
        if let Err(r) = exercise(seed) {
            panic!("seed {:?} rejected: {r}", String::from_utf8_lossy(seed));
        }
    }

    panic::set_hook(Box::new(|_| {}));
    for i in 0..args.iterations {
        mutate(&mut rng, &pool, &mut input);
        match panic::catch_unwind(|| exercise(&input)) {
            Ok(Ok(_)) => {
                accepted += 1;
                if pool.len() < 4096 {
                    pool.push(input.clone());
                } else {
                    let slot = rng.below(pool.len());
                    pool[slot] = input.clone();
                }
            }
            Ok(Err(reason)) => counts.incr(reason),
            Err(payload) => {
                let _ = panic::take_hook();
                let msg = payload
                    .downcast_ref::<String>()
                    .map(String::as_str)
                    .or_else(|| payload.downcast_ref::<&str>().copied())
                    .unwrap_or("(no message)");
                eprintln!(
                    "FOUND a failing input at iteration {i} (seed {}):",
                    args.seed
                );
                eprintln!("  panic: {msg}");
                eprintln!("  input: b\"{}\"", input.escape_ascii());
                eprintln!(
                    "replay: cargo run --release --example fuzz_net -- --seed {} --iterations {}",
                    args.seed,
                    i + 1
                );
                return ExitCode::FAILURE;
            }
        }
    }

    let elapsed = started.elapsed();
    println!(
        "{} inputs in {:.1} s (seed {}): {accepted} accepted, {} rejected, no failure",
        args.iterations,
        elapsed.as_secs_f64(),
        args.seed,
        counts.total()
    );
    for (name, n) in counts.iter().filter(|&(_, n)| n > 0) {
        println!("  {name:<18} {n}");
    }
    ExitCode::SUCCESS
}
