//! Frame-level tests: round trips of every message, and corrupted, truncated, lost and
//! concatenated frames on a byte stream.

use crate::frame::{self, FrameDecoder, FrameError, MAX_WIRE};
use crate::msg::*;
use crate::seq::SeqTracker;
use proptest::prelude::*;
use std::vec::Vec;

fn all_commands() -> Vec<Command> {
    let mut codes = [0i16; MAX_FEED];
    for (i, c) in codes.iter_mut().enumerate() {
        *c = (i as i16 - 20) * 1000;
    }
    let mut metres = [0f32; MAX_FEED];
    for (i, m) in metres.iter_mut().enumerate() {
        *m = i as f32 * -1.5e-9;
    }
    metres[3] = f32::NAN;
    metres[4] = -0.0;
    std::vec![
        Command::Ping { nonce: 0xDEAD_BEEF },
        Command::SetParam {
            id: 7,
            value: 1.25e-9,
        },
        Command::ApplyConfig,
        Command::Start(Mode::Dive),
        Command::Start(Mode::Sve),
        Command::Stop,
        Command::SetSource(Source::Timer { period_ticks: 250 }),
        Command::SetSource(Source::Feed),
        Command::Feed(FeedBlock {
            first_index: 96,
            len: MAX_FEED as u8,
            samples: FeedSamples::Codes(codes),
        }),
        Command::Feed(FeedBlock {
            first_index: 5,
            len: 7,
            samples: FeedSamples::Metres({
                let mut m = [0f32; MAX_FEED];
                m[..7].copy_from_slice(&metres[..7]);
                m
            }),
        }),
        Command::SetTelemetry {
            per_sample: PerSample::Full,
            status_every: 1000,
        },
        Command::SetTelemetry {
            per_sample: PerSample::Blocks,
            status_every: 0,
        },
        Command::RequestStatus,
        Command::SetSource(Source::Table),
        Command::Bench {
            mode: BenchMode::Stopped,
            steps: 1,
            period_ticks: 2,
        },
        Command::Bench {
            mode: BenchMode::Start(Mode::Sve),
            steps: 10_000,
            period_ticks: 50,
        },
        Command::Bench {
            mode: BenchMode::Continue { time_step: true },
            steps: 12_000,
            period_ticks: 100,
        },
        Command::Bench {
            mode: BenchMode::Continue { time_step: false },
            steps: 12_000,
            period_ticks: 100,
        },
        Command::Calibrate { iterations: 12345 },
        Command::Exit { code: 3 },
    ]
}

fn all_telemetry() -> Vec<Telemetry> {
    std::vec![
        Telemetry::Hello {
            protocol: PROTOCOL_VERSION,
            board: board::QEMU_MPS2_AN500,
            core: 0,
        },
        Telemetry::Ack {
            cmd_seq: 9,
            code: ack::INVALID,
        },
        Telemetry::Step(StepFrame {
            index: 1,
            d_m: 1e-9,
            u_code: -32768,
            dac_word: 0,
            u_m: -3.0e-6,
            x_m: 1e-6,
            y_m: -1e-6,
            status: 0x0A00_A5A5,
            estimates: [1.0, 2.0, f32::INFINITY],
        }),
        Telemetry::StepBlock({
            let mut b = StepBlockFrame {
                first_index: 480,
                len: MAX_FEED as u8,
                digest: 0x1234_5678,
                ..Default::default()
            };
            for i in 0..MAX_FEED {
                b.u_codes[i] = (i as i16) * -600;
                b.status[i] = i as u16;
            }
            b
        }),
        Telemetry::Record(RecordFrame {
            index: 77,
            mode: 2,
            number: 3,
            ix: 49,
            iy: 3,
            variant: 1,
            x_m: 0.0,
            y_m: 5e-6,
            c_ns_per_m: 1e-5,
            k_n_per_m: 0.05,
            height_m: 3e-7,
            depth_m: 1.2e-7,
            offset_n: -0.0,
            centre_m: f32::NAN,
            flags: 0x4004,
            samples: 980,
        }),
        Telemetry::Status(StatusFrame {
            samples: 1,
            starved: 2,
            telemetry_dropped: 3,
            rx_bad_frames: 4,
            rx_lost_frames: 5,
            state: 1,
            estimates: [0.0; 3],
            estimator_late: 6,
            blocks_dropped: 7,
            samples_dropped: 8,
            tones_late: 9,
        }),
        Telemetry::Bench(BenchFrame {
            mode: 1,
            steps: 10_000,
            ticks: 123_456,
            idle_iterations: 99,
            idle_insns_per_iteration: 4,
            fixed_insns: 3,
            step_ticks: 7,
            loop_ticks: 8,
            estimator_ticks: 9,
            estimator_blocks: 10,
        }),
        Telemetry::ConfigRejected(ConfigRejectedFrame::new(
            "sve.estimator.gamma",
            1e9,
            "the gradient law needs T·γ/α ≤ 1 to be stable for every input; lower γ or raise α",
        )),
        Telemetry::ConfigRejected(ConfigRejectedFrame::new(
            &"x".repeat(100),
            f64::NAN,
            &"é".repeat(200),
        )),
        Telemetry::Calibration(CalibrationFrame {
            iterations: 1,
            instructions: 2,
            ticks: 3,
        }),
    ]
}

/// Bitwise equality (NaN-safe) through the debug representation of the bits.
fn same_bits<M: core::fmt::Debug>(a: &M, b: &M) -> bool {
    std::format!("{a:?}") == std::format!("{b:?}")
}

#[test]
fn every_message_round_trips() {
    for (i, c) in all_commands().into_iter().enumerate() {
        let mut buf = [0u8; MAX_WIRE];
        let n = frame::encode(i as u32, &c, &mut buf).unwrap();
        assert_eq!(buf[n - 1], 0);
        assert!(!buf[..n - 1].contains(&0));
        let (seq, back): (u32, Command) = frame::decode_frame(&buf[..n - 1]).unwrap();
        assert_eq!(seq, i as u32);
        assert!(same_bits(&c, &back), "{c:?} != {back:?}");
    }
    for (i, t) in all_telemetry().into_iter().enumerate() {
        let mut buf = [0u8; MAX_WIRE];
        let n = frame::encode(1000 + i as u32, &t, &mut buf).unwrap();
        let (seq, back): (u32, Telemetry) = frame::decode_frame(&buf[..n - 1]).unwrap();
        assert_eq!(seq, 1000 + i as u32);
        assert!(same_bits(&t, &back), "{t:?} != {back:?}");
    }
}

#[test]
fn bad_frames_are_reported_not_panicked() {
    let mut buf = [0u8; MAX_WIRE];
    let n = frame::encode(3, &Command::Stop, &mut buf).unwrap();
    // A flipped bit is a CRC failure.
    let mut bad = buf;
    bad[2] ^= 0x10;
    if bad[2] == 0 {
        bad[2] = 0x55;
    }
    let r: Result<(u32, Command), _> = frame::decode_frame(&bad[..n - 1]);
    assert!(matches!(r, Err(FrameError::Crc) | Err(FrameError::Cobs(_))));
    // Too short.
    let r: Result<(u32, Command), _> = frame::decode_frame(&[0x02, 0x01]);
    assert_eq!(r, Err(FrameError::TooShort));
    // Too long on the stream.
    let mut d = FrameDecoder::new();
    for _ in 0..MAX_WIRE + 10 {
        assert!(d.push::<Command>(0x01).is_none());
    }
    assert_eq!(d.push::<Command>(0), Some(Err(FrameError::TooLong)));
    // The decoder recovers at the next frame.
    let mut got = None;
    for &b in &buf[..n] {
        if let Some(r) = d.push::<Command>(b) {
            got = Some(r);
        }
    }
    assert_eq!(got, Some(Ok((3, Command::Stop))));
}

#[test]
fn unknown_kind_and_trailing_bytes() {
    assert_eq!(
        Command::decode(&[0x7F]),
        Err(DecodeError::UnknownKind(0x7F))
    );
    assert_eq!(Command::decode(&[0x05, 0x00]), Err(DecodeError::Trailing));
    assert_eq!(Command::decode(&[0x04, 0x09]), Err(DecodeError::BadValue));
    assert_eq!(Telemetry::decode(&[0x83, 1, 2]), Err(DecodeError::Short));
}

/// A stream of frames, a random subset of them removed or damaged on the way: every frame
/// is either delivered intact or accounted for as lost, and damaged ones are reported.
/// Returns (delivered, rejected, lost, expected delivered).
fn run_lossy_stream(n: u32, fate: &[u8], flip_at: &[usize]) -> (u64, u64, u64, u64) {
    let msgs = all_telemetry();
    let mut stream = Vec::new();
    let mut expected = Vec::new();
    // Bytes of a truncated frame waiting in the stream without a delimiter: they merge with
    // the next frame that reaches the stream (dropped frames do not), damaging it.
    let mut partial_pending = false;
    for seq in 0..n {
        let m = &msgs[seq as usize % msgs.len()];
        let mut buf = [0u8; MAX_WIRE];
        let len = frame::encode(seq, m, &mut buf).unwrap();
        let arg = flip_at[seq as usize % flip_at.len()];
        match fate[seq as usize % fate.len()] % 8 {
            0 => {} // dropped whole
            1 => {
                // Corrupt one byte (never into a delimiter, which would split the frame).
                let at = arg % (len - 1);
                buf[at] = if buf[at] == 0xFF { 0x01 } else { buf[at] + 1 };
                stream.extend_from_slice(&buf[..len]);
                partial_pending = false;
            }
            2 => {
                // Lose the tail, delimiter included: the frame merges with the next one,
                // which is then damaged too.
                let keep = arg % (len - 1);
                stream.extend_from_slice(&buf[..keep]);
                partial_pending |= keep > 0;
            }
            _ => {
                stream.extend_from_slice(&buf[..len]);
                if !partial_pending {
                    expected.push(seq);
                }
                partial_pending = false;
            }
        }
    }
    // A final delimiter so a truncated last frame is still seen as bad.
    stream.push(0);
    let mut dec = FrameDecoder::new();
    let mut seqs = SeqTracker::starting_at(0);
    let mut got = Vec::new();
    let mut bad = 0u64;
    for b in stream {
        match dec.push::<Telemetry>(b) {
            Some(Ok((seq, m))) => {
                assert!(same_bits(&m, &msgs[seq as usize % msgs.len()]));
                seqs.observe(seq);
                got.push(seq);
            }
            Some(Err(_)) => bad += 1,
            None => {}
        }
    }
    // Exactly the undamaged frames arrive (a corruption that still passes the CRC would
    // show up here).
    assert_eq!(got, expected);
    // Every sequence number up to the highest received is delivered or counted lost. Frames
    // after the last delivered one cannot show as gaps; the sender's counters in the Status
    // frame and the replay's sample count cover those.
    let highest = seqs.highest().map(|h| h as u64 + 1).unwrap_or(0);
    assert_eq!(seqs.lost() + got.len() as u64, highest);
    (got.len() as u64, bad, seqs.lost(), expected.len() as u64)
}

#[test]
fn lossy_stream_is_fully_accounted() {
    let fate: Vec<u8> = (0..97u32).map(|i| (i * 37 % 11) as u8).collect();
    let flips: Vec<usize> = (0..31usize).map(|i| i * 13 + 1).collect();
    let (ok, bad, lost, expected) = run_lossy_stream(5000, &fate, &flips);
    assert_eq!(ok, expected);
    assert!(ok > 1000 && bad > 500 && lost > 1000, "{ok} {bad} {lost}");
}

proptest! {
    #[test]
    fn prop_lossy_stream(fate in proptest::collection::vec(any::<u8>(), 1..64),
                         flips in proptest::collection::vec(any::<usize>(), 1..16),
                         n in 1u32..600) {
        let (ok, _bad, _lost, expected) = run_lossy_stream(n, &fate, &flips);
        prop_assert_eq!(ok, expected);
    }

    #[test]
    fn prop_decoder_never_panics(bytes in proptest::collection::vec(any::<u8>(), 0..2000)) {
        let mut d = FrameDecoder::new();
        for b in bytes {
            let _ = d.push::<Command>(b);
            let _ = d.push::<Telemetry>(b);
        }
    }

    #[test]
    fn prop_feed_round_trip(first in any::<u32>(), codes in proptest::collection::vec(any::<i16>(), 0..=MAX_FEED)) {
        let mut c = [0i16; MAX_FEED];
        c[..codes.len()].copy_from_slice(&codes);
        let cmd = Command::Feed(FeedBlock { first_index: first, len: codes.len() as u8, samples: FeedSamples::Codes(c) });
        let mut buf = [0u8; MAX_WIRE];
        let n = frame::encode(first, &cmd, &mut buf).unwrap();
        let (_, back): (u32, Command) = frame::decode_frame(&buf[..n - 1]).unwrap();
        prop_assert_eq!(back, cmd);
    }
}

#[test]
fn step_fields_length_and_block_matching() {
    let frames: Vec<StepFrame> = (0..10u32)
        .map(|i| StepFrame {
            index: 100 + i,
            u_code: i as i32 * 3 - 10,
            status: 2,
            estimates: [i as f32, 0.5, -0.0],
            ..Default::default()
        })
        .collect();
    let mut buf = [0u8; 64];
    let mut w = crate::wire::Writer::new(&mut buf);
    frames[0].encode_fields(&mut w).unwrap();
    assert_eq!(w.len(), STEP_FIELDS_LEN);
    let mut b = StepBlockFrame {
        first_index: 100,
        len: 10,
        digest: step_digest(&frames),
        ..Default::default()
    };
    for (i, f) in frames.iter().enumerate() {
        b.u_codes[i] = f.u_code as i16;
        b.status[i] = f.status as u16;
    }
    assert!(b.matches(&frames));
    // One bit anywhere in any field breaks the match.
    let mut other = frames.clone();
    other[7].estimates[2] = 0.0; // -0.0 → +0.0
    assert!(!b.matches(&other));
    let mut other = frames.clone();
    other[3].y_m = f32::from_bits(other[3].y_m.to_bits() ^ 1);
    assert!(!b.matches(&other));
    assert!(!b.matches(&frames[..9]));
}

#[test]
fn config_rejected_is_cut_at_character_boundaries() {
    let c = ConfigRejectedFrame::new("dive.estimator.alpha", -1.0, "must be a finite number > 0");
    assert_eq!(c.field(), "dive.estimator.alpha");
    assert_eq!(c.reason(), "must be a finite number > 0");
    let long = ConfigRejectedFrame::new("f", 0.0, &"é".repeat(200));
    assert_eq!(long.reason().len(), REASON_LEN);
    assert!(long.reason().chars().all(|ch| ch == 'é'));
    let mut buf = [0u8; MAX_WIRE];
    let n = frame::encode(1, &Telemetry::ConfigRejected(long), &mut buf).unwrap();
    let (_, back): (u32, Telemetry) = frame::decode_frame(&buf[..n - 1]).unwrap();
    assert_eq!(back, Telemetry::ConfigRejected(long));
}
