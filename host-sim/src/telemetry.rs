//! The host end of the firmware link: reading telemetry frames, sending commands, the QEMU
//! target, replay, and turning a telemetry stream into a recording.
//!
//! Frames are `COBS(seq | message | CRC-32) 0x00` (crate `visco-protocol`). Nothing is
//! dropped silently: every rejected frame is counted by cause (CRC, COBS, length, decoding)
//! and every missing sequence number is counted as lost ([`LinkStats`]); [`Event`] hands
//! them to the caller in stream order as well, and a recording written from a stream with
//! losses says so in its metadata ([`write_recording_csv`]).
//!
//! This file depends only on `std` and `visco-protocol`. Replay and lockstep against the host
//! build of the core, with realistic inputs, are in [`crate::replay`].

use std::collections::VecDeque;
use std::fmt;
use std::io::{self, Read, Write};
use std::time::{Duration, Instant};
use visco_protocol::{
    frame, Command, FrameDecoder, FrameError, RecordFrame, SeqEvent, SeqTracker, StatusFrame,
    StepBlockFrame, StepFrame, Telemetry, MAX_WIRE,
};

/// Counts of everything that happened on one telemetry stream.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct LinkStats {
    /// Bytes read.
    pub bytes: u64,
    /// Frames delivered intact.
    pub frames: u64,
    /// Frames lost: sequence numbers never received (includes the corrupted ones, which
    /// are missing from the sequence too, and frames the firmware could not queue).
    pub lost: u64,
    /// Frames rejected by their CRC.
    pub crc_errors: u64,
    /// Frames rejected as invalid COBS.
    pub cobs_errors: u64,
    /// Frames too short or too long.
    pub length_errors: u64,
    /// Frames with a good CRC that did not decode (protocol version mismatch?).
    pub decode_errors: u64,
    /// Frames received twice.
    pub duplicates: u64,
    /// Frames that arrived after being counted lost.
    pub stale: u64,
}

impl LinkStats {
    /// Frames that arrived damaged.
    pub fn corrupted(&self) -> u64 {
        self.crc_errors + self.cobs_errors + self.length_errors + self.decode_errors
    }
    /// True when nothing was lost or damaged.
    pub fn is_clean(&self) -> bool {
        self.lost == 0 && self.corrupted() == 0 && self.duplicates == 0 && self.stale == 0
    }
}

impl fmt::Display for LinkStats {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "{} frames ({} bytes), {} lost by sequence gaps, {} corrupted (CRC {}, COBS {}, \
             length {}, undecodable {}), {} duplicate, {} late",
            self.frames,
            self.bytes,
            self.lost,
            self.corrupted(),
            self.crc_errors,
            self.cobs_errors,
            self.length_errors,
            self.decode_errors,
            self.duplicates,
            self.stale
        )
    }
}

/// One thing that happened on the stream.
// A frame is moved once from the decoder to the caller; boxing it would allocate per frame.
#[allow(clippy::large_enum_variant)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Event {
    /// A frame, intact.
    Frame {
        /// Its sequence number.
        seq: u32,
        /// The message.
        msg: Telemetry,
    },
    /// Sequence numbers skipped before this frame (provisionally lost: a late frame may
    /// still fill the hole; [`LinkStats::lost`] has the final count).
    Gap {
        /// How many numbers were skipped.
        missing: u32,
        /// The number that revealed the gap.
        at: u32,
    },
    /// A frame rejected, with the reason.
    Corrupt(FrameError),
}

/// Reads frames from a byte stream.
pub struct TelemetryReader<R> {
    inner: R,
    dec: FrameDecoder,
    seq: SeqTracker,
    stats: LinkStats,
    buf: Box<[u8]>,
    pos: usize,
    len: usize,
    pending: VecDeque<Event>,
}

impl<R: Read> TelemetryReader<R> {
    /// A reader for a stream whose first frame has sequence number 0 (a firmware boot).
    pub fn new(inner: R) -> Self {
        Self::with_tracker(inner, SeqTracker::starting_at(0))
    }

    /// A reader joining a stream in the middle (the first frame seen sets the start).
    pub fn joining(inner: R) -> Self {
        Self::with_tracker(inner, SeqTracker::new())
    }

    fn with_tracker(inner: R, seq: SeqTracker) -> Self {
        Self {
            inner,
            dec: FrameDecoder::new(),
            seq,
            stats: LinkStats::default(),
            buf: vec![0u8; 64 * 1024].into_boxed_slice(),
            pos: 0,
            len: 0,
            pending: VecDeque::new(),
        }
    }

    /// The counts so far (losses include holes not yet filled).
    pub fn stats(&self) -> LinkStats {
        let mut s = self.stats;
        s.lost = self.seq.lost();
        s.duplicates = self.seq.duplicates();
        s.stale = self.seq.stale();
        s
    }

    /// The underlying reader.
    pub fn get_mut(&mut self) -> &mut R {
        &mut self.inner
    }

    /// The next event; `None` at the end of the stream. Read errors (including time-outs)
    /// are returned as they are.
    pub fn next_event(&mut self) -> io::Result<Option<Event>> {
        loop {
            if let Some(e) = self.pending.pop_front() {
                return Ok(Some(e));
            }
            if self.pos == self.len {
                let n = loop {
                    match self.inner.read(&mut self.buf) {
                        Err(e) if e.kind() == io::ErrorKind::Interrupted => continue,
                        r => break r?,
                    }
                };
                if n == 0 {
                    return Ok(None);
                }
                self.stats.bytes += n as u64;
                self.pos = 0;
                self.len = n;
            }
            while self.pos < self.len && self.pending.is_empty() {
                let b = self.buf[self.pos];
                self.pos += 1;
                match self.dec.push::<Telemetry>(b) {
                    None => {}
                    Some(Ok((seq, msg))) => {
                        match self.seq.observe(seq) {
                            SeqEvent::Gap(missing) => {
                                self.pending.push_back(Event::Gap { missing, at: seq })
                            }
                            SeqEvent::Duplicate | SeqEvent::Stale => continue,
                            SeqEvent::InOrder | SeqEvent::Late => {}
                        }
                        self.stats.frames += 1;
                        self.pending.push_back(Event::Frame { seq, msg });
                    }
                    Some(Err(e)) => {
                        match e {
                            FrameError::Crc => self.stats.crc_errors += 1,
                            FrameError::Cobs(_) => self.stats.cobs_errors += 1,
                            FrameError::TooShort | FrameError::TooLong => {
                                self.stats.length_errors += 1
                            }
                            FrameError::Decode(_) => self.stats.decode_errors += 1,
                        }
                        self.pending.push_back(Event::Corrupt(e));
                    }
                }
            }
        }
    }

    /// The next intact frame (gaps and rejected frames are counted in [`Self::stats`]).
    pub fn next_frame(&mut self) -> io::Result<Option<(u32, Telemetry)>> {
        while let Some(e) = self.next_event()? {
            if let Event::Frame { seq, msg } = e {
                return Ok(Some((seq, msg)));
            }
        }
        Ok(None)
    }
}

/// Decodes a whole telemetry log (the raw bytes of a stream, as saved by a host).
pub fn decode_log(bytes: &[u8]) -> (Vec<(u32, Telemetry)>, LinkStats) {
    let mut r = TelemetryReader::new(bytes);
    let mut out = Vec::new();
    // Reading from a slice cannot fail.
    while let Ok(Some((seq, msg))) = r.next_frame() {
        out.push((seq, msg));
    }
    (out, r.stats())
}

/// Sends commands, numbering the frames.
pub struct CommandWriter<W> {
    inner: W,
    seq: u32,
}

impl<W: Write> CommandWriter<W> {
    /// A writer whose first frame is number 0.
    pub fn new(inner: W) -> Self {
        Self { inner, seq: 0 }
    }
    /// Sends one command; returns its sequence number (echoed by the firmware's Ack).
    pub fn send(&mut self, cmd: &Command) -> io::Result<u32> {
        let mut buf = [0u8; MAX_WIRE];
        let n = frame::encode(self.seq, cmd, &mut buf)
            .map_err(|_| io::Error::new(io::ErrorKind::InvalidInput, "command too long"))?;
        self.inner.write_all(&buf[..n])?;
        let s = self.seq;
        self.seq = self.seq.wrapping_add(1);
        Ok(s)
    }
    /// Flushes the underlying writer.
    pub fn flush(&mut self) -> io::Result<()> {
        self.inner.flush()
    }
    /// The underlying writer.
    pub fn get_mut(&mut self) -> &mut W {
        &mut self.inner
    }
}

/// Writes replay Step frames as a recording (`shared/spec/recording.md`): metadata first,
/// including the link counts, so a recording made from a lossy stream says so; then
/// `t_s,u_m,d_m,x_m,y_m` and the firmware's extra columns (`u_code,status,c,k,h`), which
/// readers keep and ignore. `metadata` supplies the keys the telemetry does not carry
/// (mode, cantilever, tip radius, …).
///
/// A row pairs the deflection of a sample with the U, X, Y the DACs held while it was taken:
/// the outputs of the *previous* step (a step's U is applied from the next sample on). So a
/// row needs its predecessor: the first sample, and a sample after a missing one, give no
/// row (`# telemetry_samples_missing` counts the missing ones). `u_code`, `status` and the
/// estimates are those of the step that took the row's D.
pub fn write_recording_csv<W: Write>(
    mut out: W,
    steps: &[StepFrame],
    sample_rate_hz: f64,
    metadata: &[(&str, String)],
    stats: &LinkStats,
) -> io::Result<()> {
    writeln!(out, "# visco-recording: 1")?;
    writeln!(out, "# sample_rate_hz: {sample_rate_hz}")?;
    for (k, v) in metadata {
        writeln!(out, "# {k}: {v}")?;
    }
    writeln!(out, "# telemetry_frames: {}", stats.frames)?;
    writeln!(out, "# telemetry_frames_lost: {}", stats.lost)?;
    writeln!(out, "# telemetry_frames_corrupted: {}", stats.corrupted())?;
    let missing_samples = match (steps.first(), steps.last()) {
        (Some(a), Some(b)) => (b.index.wrapping_sub(a.index) as u64 + 1) - steps.len() as u64,
        _ => 0,
    };
    writeln!(out, "# telemetry_samples_missing: {missing_samples}")?;
    writeln!(out, "t_s,u_m,d_m,x_m,y_m,u_code,status,c,k,h")?;
    for w in steps.windows(2) {
        let (held, s) = (&w[0], &w[1]);
        if held.index.wrapping_add(1) != s.index {
            continue;
        }
        writeln!(
            out,
            "{:e},{:e},{:e},{:e},{:e},{},{},{:e},{:e},{:e}",
            s.index as f64 / sample_rate_hz,
            held.u_m,
            s.d_m,
            held.x_m,
            held.y_m,
            s.u_code,
            s.status,
            s.estimates[0],
            s.estimates[1],
            s.estimates[2]
        )?;
    }
    Ok(())
}

/// Replay input: what is fed to the firmware's ADC path.
#[derive(Clone, Copy, Debug)]
pub enum ReplayInput<'a> {
    /// ADC codes (signed, relative to mid-scale), converted on target as on the board.
    Codes(&'a [i16]),
    /// Deflection in metres, handed to `step` unchanged.
    Metres(&'a [f32]),
}

impl ReplayInput<'_> {
    /// Number of samples.
    pub fn len(&self) -> usize {
        match self {
            ReplayInput::Codes(c) => c.len(),
            ReplayInput::Metres(m) => m.len(),
        }
    }
    /// True when there are no samples.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// What a replay brought back.
#[derive(Clone, Debug)]
pub struct ReplayOutput {
    /// One Step frame per sample, in order (`PerSample::Full`; missing ones are counted in
    /// `stats`).
    pub steps: Vec<StepFrame>,
    /// Compact blocks covering the samples in order (`PerSample::Blocks`).
    pub blocks: Vec<StepBlockFrame>,
    /// Records (finished taps / pixels).
    pub records: Vec<RecordFrame>,
    /// Firmware counters after the replay.
    pub status: Option<StatusFrame>,
    /// Link counts.
    pub stats: LinkStats,
    /// Wall time of the sample stream.
    pub elapsed: Duration,
}

/// What a firmware's status counts as lost or late ([`StatusFrame::losses`]), as
/// "3 blocks dropped, 1 block closes with an estimator result out"; `None` when nothing was.
pub fn firmware_losses(st: &StatusFrame) -> Option<String> {
    let lost: Vec<String> = st
        .losses()
        .iter()
        .filter(|(_, n)| *n != 0)
        .map(|(what, n)| format!("{n} {what}"))
        .collect();
    (!lost.is_empty()).then(|| lost.join(", "))
}

/// Compares per-sample outputs bit for bit; the first differing sample index and a
/// description, or `None` when identical (lengths included).
pub fn first_difference(a: &[StepFrame], b: &[StepFrame]) -> Option<(usize, String)> {
    let bits = |s: &StepFrame| {
        (
            s.index,
            s.d_m.to_bits(),
            s.u_code,
            s.dac_word,
            s.u_m.to_bits(),
            s.x_m.to_bits(),
            s.y_m.to_bits(),
            s.status,
            s.estimates.map(f32::to_bits),
        )
    };
    for (i, (x, y)) in a.iter().zip(b).enumerate() {
        if bits(x) != bits(y) {
            return Some((i, format!("firmware {x:?}\n host    {y:?}")));
        }
    }
    if a.len() != b.len() {
        return Some((
            a.len().min(b.len()),
            format!("lengths differ: {} vs {}", a.len(), b.len()),
        ));
    }
    None
}

/// Checks compact blocks against full frames computed elsewhere (the host): the blocks must
/// cover every sample in order and each must match bit for bit. The first failing sample
/// and why, or `None`.
pub fn check_blocks(blocks: &[StepBlockFrame], reference: &[StepFrame]) -> Option<(usize, String)> {
    let mut next = 0usize;
    for b in blocks {
        let first = b.first_index as usize;
        let end = first + b.len as usize;
        if first != next {
            return Some((next, format!("samples {next}..{first} missing")));
        }
        match reference.get(first..end) {
            Some(r) if b.matches(r) => {}
            Some(r) => {
                let at = (0..r.len()).find(|&i| {
                    b.u_codes[i] != r[i].u_code.clamp(-32768, 32767) as i16
                        || b.status[i] != r[i].status as u16
                });
                return Some((
                    first,
                    match at {
                        Some(i) => format!(
                            "sample {}: firmware u_code {} status {:#x}, host u_code {} status {:#x}",
                            first + i,
                            b.u_codes[i],
                            b.status[i],
                            r[i].u_code,
                            r[i].status
                        ),
                        None => format!(
                            "samples {first}..{end}: same DAC codes and status flags, different \
                             digest (U in metres, X/Y, phase or estimates differ): rerun with \
                             full per-sample frames"
                        ),
                    },
                ));
            }
            None => return Some((first, format!("block {first}..{end} beyond the input"))),
        }
        next = end;
    }
    (next != reference.len()).then(|| (next, format!("samples {next}.. missing")))
}

/// Compares record frames bit for bit (NaN-safe); the first differing one, or `None`.
pub fn first_record_difference(a: &[RecordFrame], b: &[RecordFrame]) -> Option<(usize, String)> {
    let bits = |r: &RecordFrame| {
        (
            r.index,
            r.mode,
            r.number,
            r.ix,
            r.iy,
            r.variant,
            [
                r.x_m,
                r.y_m,
                r.c_ns_per_m,
                r.k_n_per_m,
                r.height_m,
                r.depth_m,
                r.offset_n,
                r.centre_m,
            ]
            .map(f32::to_bits),
            r.flags,
            r.samples,
        )
    };
    for (i, (x, y)) in a.iter().zip(b).enumerate() {
        if bits(x) != bits(y) {
            return Some((i, format!("firmware {x:?}\n host    {y:?}")));
        }
    }
    (a.len() != b.len()).then(|| {
        (
            a.len().min(b.len()),
            format!(
                "{} records from the firmware, {} from the host",
                a.len(),
                b.len()
            ),
        )
    })
}

/// The QEMU target: an emulated `mps2-an500` running the firmware image, its UART0 on a
/// Unix socket, and its semihosting (defmt) output in a file.
#[cfg(unix)]
pub mod qemu {
    use super::*;
    use std::os::unix::net::{UnixListener, UnixStream};
    use std::path::{Path, PathBuf};
    use std::process::{Child, Command as Process, ExitStatus, Stdio};
    use visco_protocol::{ack, FeedBlock, FeedSamples, Mode, PerSample, Source, MAX_FEED};

    /// How to start QEMU.
    #[derive(Clone, Debug)]
    pub struct QemuOptions {
        /// The firmware ELF (QEMU board build).
        pub elf: PathBuf,
        /// Where the semihosting output (the binary defmt stream) goes.
        pub defmt_out: PathBuf,
        /// `-icount shift=N` (deterministic virtual time, 2^N ns per instruction); `None`
        /// runs as fast as possible.
        pub icount_shift: Option<u32>,
        /// Time allowed for QEMU to connect and for any single answer.
        pub timeout: Duration,
        /// QEMU machine: `mps2-an500` (Cortex-M7, default) or `mps2-an385` (Cortex-M3; same
        /// peripheral map, for the `thumbv7m-none-eabi` build).
        pub machine: String,
        /// QEMU CPU: `cortex-m7` or `cortex-m3`.
        pub cpu: String,
    }

    impl QemuOptions {
        /// Defaults: no icount, defmt output next to the ELF, 60 s time-out.
        pub fn new(elf: impl Into<PathBuf>) -> Self {
            let elf = elf.into();
            let defmt_out = elf.with_extension("defmt.bin");
            Self {
                elf,
                defmt_out,
                icount_shift: None,
                timeout: Duration::from_secs(60),
                machine: "mps2-an500".into(),
                cpu: "cortex-m7".into(),
            }
        }
    }

    /// The `qemu-system-arm` argument list for `opts` with UART0 on `socket`.
    pub fn qemu_args(opts: &QemuOptions, socket: &Path) -> Vec<String> {
        let mut a: Vec<String> = [
            "-machine",
            opts.machine.as_str(),
            "-cpu",
            opts.cpu.as_str(),
            "-display",
            "none",
            "-monitor",
            "none",
            "-semihosting-config",
            "enable=on,target=native",
        ]
        .iter()
        .map(|s| s.to_string())
        .collect();
        if let Some(shift) = opts.icount_shift {
            a.push("-icount".into());
            a.push(format!("shift={shift},sleep=off"));
        }
        // Extra QEMU arguments for experiments, e.g. VISCO_QEMU_EXTRA="-d in_asm".
        if let Ok(extra) = std::env::var("VISCO_QEMU_EXTRA") {
            a.extend(extra.split_whitespace().map(str::to_string));
        }
        a.push("-chardev".into());
        a.push(format!("socket,id=link,path={}", socket.display()));
        a.push("-serial".into());
        a.push("chardev:link".into());
        a.push("-kernel".into());
        a.push(opts.elf.display().to_string());
        a
    }

    /// A running QEMU with the firmware, and the link to it.
    pub struct QemuLink {
        child: Child,
        socket: PathBuf,
        /// Telemetry from the firmware.
        pub reader: TelemetryReader<UnixStream>,
        /// Commands to the firmware.
        pub writer: CommandWriter<UnixStream>,
        /// Frames that arrived while waiting for something else (in order).
        pub backlog: Vec<Telemetry>,
        /// The core the firmware announced in its Hello (1: f32, 2: Q31.32).
        pub core: u8,
        timeout: Duration,
        lockstep_index: u32,
    }

    fn err(msg: String) -> io::Error {
        io::Error::other(msg)
    }

    impl QemuLink {
        /// Starts QEMU and waits for the firmware's Hello.
        pub fn spawn(opts: &QemuOptions) -> io::Result<Self> {
            static NEXT: std::sync::atomic::AtomicU32 = std::sync::atomic::AtomicU32::new(0);
            let socket = std::env::temp_dir().join(format!(
                "visco-qemu-{}-{}.sock",
                std::process::id(),
                NEXT.fetch_add(1, std::sync::atomic::Ordering::Relaxed)
            ));
            let _ = std::fs::remove_file(&socket);
            let listener = UnixListener::bind(&socket)?;
            listener.set_nonblocking(true)?;
            let defmt = std::fs::File::create(&opts.defmt_out)?;
            let mut child = Process::new("qemu-system-arm")
                .args(qemu_args(opts, &socket))
                .stdin(Stdio::null())
                .stdout(defmt)
                .stderr(Stdio::piped())
                .spawn()
                .map_err(|e| err(format!("cannot start qemu-system-arm: {e}")))?;
            let deadline = Instant::now() + opts.timeout;
            let stream = loop {
                match listener.accept() {
                    Ok((s, _)) => break s,
                    Err(e) if e.kind() == io::ErrorKind::WouldBlock => {
                        if let Some(status) = child.try_wait()? {
                            let mut msg = String::new();
                            if let Some(mut e) = child.stderr.take() {
                                let _ = e.read_to_string(&mut msg);
                            }
                            let _ = std::fs::remove_file(&socket);
                            return Err(err(format!(
                                "qemu exited ({status}) before connecting: {msg}"
                            )));
                        }
                        if Instant::now() > deadline {
                            let _ = child.kill();
                            let _ = std::fs::remove_file(&socket);
                            return Err(err("qemu did not connect to the link socket".into()));
                        }
                        std::thread::sleep(Duration::from_millis(5));
                    }
                    Err(e) => return Err(e),
                }
            };
            stream.set_nonblocking(false)?;
            stream.set_read_timeout(Some(opts.timeout))?;
            let w = stream.try_clone()?;
            let mut link = Self {
                child,
                socket,
                reader: TelemetryReader::new(stream),
                writer: CommandWriter::new(w),
                backlog: Vec::new(),
                core: 0,
                timeout: opts.timeout,
                lockstep_index: 0,
            };
            match link.next_message()? {
                Telemetry::Hello { protocol, core, .. }
                    if protocol == visco_protocol::PROTOCOL_VERSION =>
                {
                    link.core = core
                }
                other => {
                    return Err(err(format!(
                        "expected Hello from the firmware, got {other:?}"
                    )))
                }
            }
            Ok(link)
        }

        /// The next intact frame (error at end of stream or time-out).
        pub fn next_message(&mut self) -> io::Result<Telemetry> {
            match self.reader.next_frame()? {
                Some((_, m)) => Ok(m),
                None => Err(err("the firmware closed the link".into())),
            }
        }

        /// Sends a command and waits for its Ack; returns the ack code. Frames arriving in
        /// between go to [`Self::backlog`].
        pub fn command(&mut self, cmd: &Command) -> io::Result<u8> {
            let seq = self.writer.send(cmd)?;
            loop {
                match self.next_message()? {
                    Telemetry::Ack { cmd_seq, code } if cmd_seq == seq => return Ok(code),
                    other => self.backlog.push(other),
                }
            }
        }

        /// Like [`Self::command`], but an error unless the firmware answered OK (with the
        /// field and reason when it refused a configuration).
        pub fn command_ok(&mut self, cmd: &Command) -> io::Result<()> {
            match self.command(cmd)? {
                ack::OK => Ok(()),
                code => {
                    let why = self.backlog.iter().rev().find_map(|m| match m {
                        Telemetry::ConfigRejected(c) => {
                            Some(format!(": `{}` = {}: {}", c.field(), c.value, c.reason()))
                        }
                        _ => None,
                    });
                    Err(err(format!(
                        "firmware refused {cmd:?}: ack code {code}{}",
                        why.unwrap_or_default()
                    )))
                }
            }
        }

        /// Firmware counters now.
        pub fn status(&mut self) -> io::Result<StatusFrame> {
            self.command_ok(&Command::RequestStatus)?;
            let at = self
                .backlog
                .iter()
                .rposition(|m| matches!(m, Telemetry::Status(_)))
                .ok_or_else(|| err("no Status frame before the Ack".into()))?;
            match self.backlog.remove(at) {
                Telemetry::Status(s) => Ok(s),
                _ => unreachable!("checked above"),
            }
        }

        /// Feeds `input` sample by sample, starting `mode` first (or, with `None`, carrying
        /// on where the core is), and collects the per-sample outputs: one Step frame per
        /// sample (`PerSample::Full`) or compact blocks (`PerSample::Blocks`, ~10× fewer
        /// bytes). Sending runs on a second thread so the firmware never waits for the host.
        /// The core is stopped afterwards unless `keep_running` (a replay continued later,
        /// e.g. by a bench over the next samples). Sample indices start at 0.
        pub fn replay(
            &mut self,
            input: ReplayInput<'_>,
            mode: Option<Mode>,
            per_sample: PerSample,
            keep_running: bool,
        ) -> io::Result<ReplayOutput> {
            let n = input.len();
            if per_sample == PerSample::Off {
                return Err(err("a replay needs per-sample outputs".into()));
            }
            self.command_ok(&Command::SetSource(Source::Feed))?;
            self.command_ok(&Command::SetTelemetry {
                per_sample,
                status_every: 0,
            })?;
            if let Some(mode) = mode {
                self.command_ok(&Command::Start(mode))?;
            }
            let mut frames = Vec::with_capacity(n.div_ceil(MAX_FEED));
            let mut first = 0usize;
            while first < n {
                let len = (n - first).min(MAX_FEED);
                let samples = match input {
                    ReplayInput::Codes(c) => {
                        let mut a = [0i16; MAX_FEED];
                        a[..len].copy_from_slice(&c[first..first + len]);
                        FeedSamples::Codes(a)
                    }
                    ReplayInput::Metres(m) => {
                        let mut a = [0f32; MAX_FEED];
                        a[..len].copy_from_slice(&m[first..first + len]);
                        FeedSamples::Metres(a)
                    }
                };
                frames.push(Command::Feed(FeedBlock {
                    first_index: first as u32,
                    len: len as u8,
                    samples,
                }));
                first += len;
            }
            let started = Instant::now();
            let mut steps = Vec::with_capacity(if per_sample == PerSample::Full { n } else { 0 });
            let mut blocks = Vec::new();
            let mut records = Vec::new();
            let mut refused = None;
            std::thread::scope(|scope| -> io::Result<()> {
                let writer = &mut self.writer;
                let sender = scope.spawn(move || -> io::Result<()> {
                    for f in &frames {
                        writer.send(f)?;
                    }
                    writer.flush()
                });
                // Read until the last sample's output arrives (or the link fails).
                let mut result = Ok(());
                let mut done = 0usize;
                while done < n {
                    match self.reader.next_frame() {
                        Ok(Some((_, Telemetry::Step(s)))) => {
                            done = s.index as usize + 1;
                            steps.push(s);
                        }
                        Ok(Some((_, Telemetry::StepBlock(b)))) => {
                            done = b.first_index as usize + b.len as usize;
                            blocks.push(b);
                        }
                        Ok(Some((_, Telemetry::Record(r)))) => records.push(r),
                        Ok(Some((_, Telemetry::Ack { code, cmd_seq }))) => {
                            // Feed blocks are acknowledged only when refused.
                            refused = Some((cmd_seq, code));
                            break;
                        }
                        Ok(Some((_, other))) => self.backlog.push(other),
                        Ok(None) => {
                            result = Err(err("the firmware closed the link during replay".into()));
                            break;
                        }
                        Err(e) => {
                            result = Err(e);
                            break;
                        }
                    }
                }
                let sent = sender
                    .join()
                    .map_err(|_| err("replay sender panicked".into()))?;
                result.and(sent)
            })?;
            let elapsed = started.elapsed();
            if let Some((seq, code)) = refused {
                return Err(err(format!(
                    "firmware refused replay frame {seq} with ack code {code} after {} Step frames \
                     and {} blocks",
                    steps.len(),
                    blocks.len()
                )));
            }
            // Records queued with the last samples come before the next command's Ack.
            if !keep_running {
                self.command_ok(&Command::Stop)?;
            }
            self.command_ok(&Command::SetTelemetry {
                per_sample: PerSample::Off,
                status_every: 0,
            })?;
            let status = Some(self.status()?);
            records.extend(self.backlog.iter().filter_map(|m| match m {
                Telemetry::Record(r) => Some(*r),
                _ => None,
            }));
            self.backlog.retain(|m| !matches!(m, Telemetry::Record(_)));
            Ok(ReplayOutput {
                steps,
                blocks,
                records,
                status,
                stats: self.reader.stats(),
                elapsed,
            })
        }

        /// Starts a closed-loop (processor-in-the-loop) run: afterwards each
        /// [`Self::lockstep`] call feeds one deflection and returns that sample's outputs, so
        /// a host plant can compute the next deflection from the firmware's U.
        pub fn start_lockstep(&mut self, mode: Mode) -> io::Result<()> {
            self.command_ok(&Command::SetSource(Source::Feed))?;
            self.command_ok(&Command::SetTelemetry {
                per_sample: PerSample::Full,
                status_every: 0,
            })?;
            self.command_ok(&Command::Start(mode))?;
            self.lockstep_index = 0;
            Ok(())
        }

        /// One closed-loop sample (see [`Self::start_lockstep`]): the deflection in metres,
        /// handed to `step` as it is.
        pub fn lockstep(&mut self, d_m: f32) -> io::Result<StepFrame> {
            let mut m = [0f32; MAX_FEED];
            m[0] = d_m;
            self.lockstep_feed(FeedSamples::Metres(m))
        }

        /// One closed-loop sample as an ADC code, converted by the firmware's ADC path.
        pub fn lockstep_code(&mut self, code: i16) -> io::Result<StepFrame> {
            let mut c = [0i16; MAX_FEED];
            c[0] = code;
            self.lockstep_feed(FeedSamples::Codes(c))
        }

        fn lockstep_feed(&mut self, samples: FeedSamples) -> io::Result<StepFrame> {
            self.writer.send(&Command::Feed(FeedBlock {
                first_index: self.lockstep_index,
                len: 1,
                samples,
            }))?;
            loop {
                match self.next_message()? {
                    Telemetry::Step(s) if s.index == self.lockstep_index => {
                        self.lockstep_index = self.lockstep_index.wrapping_add(1);
                        return Ok(s);
                    }
                    Telemetry::Ack { code, cmd_seq } => {
                        return Err(err(format!(
                            "firmware refused lockstep frame {cmd_seq}: ack code {code}"
                        )))
                    }
                    other => self.backlog.push(other),
                }
            }
        }

        /// Ends the emulation (firmware semihosting exit) and waits for QEMU.
        pub fn exit(mut self, code: u8) -> io::Result<ExitStatus> {
            let _ = self.writer.send(&Command::Exit { code });
            let deadline = Instant::now() + self.timeout;
            loop {
                if let Some(s) = self.child.try_wait()? {
                    return Ok(s);
                }
                if Instant::now() > deadline {
                    let _ = self.child.kill();
                    return Err(err("qemu did not exit".into()));
                }
                // Keep reading so the firmware's last frames do not block its UART.
                let _ = self
                    .reader
                    .get_mut()
                    .set_read_timeout(Some(Duration::from_millis(20)));
                match self.reader.next_frame() {
                    Ok(Some((_, m))) => self.backlog.push(m),
                    Ok(None) => std::thread::sleep(Duration::from_millis(5)),
                    Err(_) => {}
                }
            }
        }
    }

    impl Drop for QemuLink {
        fn drop(&mut self) {
            if let Ok(None) = self.child.try_wait() {
                let _ = self.child.kill();
                let _ = self.child.wait();
            }
            let _ = std::fs::remove_file(&self.socket);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use visco_protocol::{board, Command, PROTOCOL_VERSION};

    /// The two rates' counters (protocol version 3) are losses but for the late chunks of
    /// tones, which the loop computes itself: a status with only those reads as no loss.
    #[test]
    fn firmware_losses_name_the_two_rates_counts_but_not_late_tones() {
        let mut st = StatusFrame {
            tones_late: 4,
            ..StatusFrame::default()
        };
        assert_eq!(firmware_losses(&st), None);
        st.estimator_late = 1;
        st.blocks_dropped = 3;
        assert_eq!(
            firmware_losses(&st).as_deref(),
            Some("1 block closes with an estimator result out, 3 blocks dropped")
        );
        st.samples_dropped = 2;
        st.starved = 5;
        assert_eq!(
            firmware_losses(&st).as_deref(),
            Some(
                "5 loop interrupts starved, 1 block closes with an estimator result out, \
                 3 blocks dropped, 2 samples dropped"
            )
        );
    }

    fn encode_stream(msgs: &[(u32, Telemetry)]) -> Vec<u8> {
        let mut v = Vec::new();
        for (seq, m) in msgs {
            let mut buf = [0u8; MAX_WIRE];
            let n = frame::encode(*seq, m, &mut buf).unwrap();
            v.extend_from_slice(&buf[..n]);
        }
        v
    }

    fn step(i: u32) -> Telemetry {
        Telemetry::Step(StepFrame {
            index: i,
            d_m: i as f32 * 1e-9,
            u_code: i as i32,
            ..Default::default()
        })
    }

    #[test]
    fn clean_stream() {
        let msgs: Vec<_> = (0..100).map(|i| (i, step(i))).collect();
        let (got, stats) = decode_log(&encode_stream(&msgs));
        assert_eq!(got, msgs);
        assert!(stats.is_clean(), "{stats}");
        assert_eq!(stats.frames, 100);
    }

    #[test]
    fn lost_and_corrupted_frames_are_counted_and_reported() {
        let msgs: Vec<_> = (0..100).map(|i| (i, step(i))).collect();
        let mut bytes = Vec::new();
        let mut expected = Vec::new();
        for (seq, m) in &msgs {
            let mut buf = [0u8; MAX_WIRE];
            let n = frame::encode(*seq, m, &mut buf).unwrap();
            match seq {
                10 | 11 | 50 => continue, // lost on the way
                // Corrupted: one byte changed, never into a delimiter.
                20 | 70 => buf[3] = if buf[3] == 0xFF { 1 } else { buf[3] + 1 },
                _ => expected.push((*seq, *m)),
            }
            assert!(!buf[..n - 1].contains(&0));
            bytes.extend_from_slice(&buf[..n]);
        }
        let mut r = TelemetryReader::new(&bytes[..]);
        let mut events = Vec::new();
        while let Some(e) = r.next_event().unwrap() {
            events.push(e);
        }
        let stats = r.stats();
        assert_eq!(stats.frames, 95);
        assert_eq!(stats.lost, 5);
        assert_eq!(stats.corrupted(), 2);
        assert!(!stats.is_clean());
        let gaps: Vec<_> = events
            .iter()
            .filter_map(|e| match e {
                Event::Gap { missing, at } => Some((*missing, *at)),
                _ => None,
            })
            .collect();
        assert_eq!(gaps, vec![(2, 12), (1, 21), (1, 51), (1, 71)]);
        assert_eq!(
            events
                .iter()
                .filter(|e| matches!(e, Event::Corrupt(_)))
                .count(),
            2
        );
        let report = stats.to_string();
        assert!(report.contains("5 lost"), "{report}");
        assert!(report.contains("2 corrupted"), "{report}");
    }

    #[test]
    fn tail_loss_needs_the_sample_count() {
        // A lost last frame leaves no gap; the replay checks the sample count instead, and
        // the recording states the missing samples.
        let msgs: Vec<_> = (0..10).map(|i| (i, step(i))).collect();
        let (got, stats) = decode_log(&encode_stream(&msgs[..9]));
        assert_eq!(got.len(), 9);
        assert_eq!(stats.lost, 0);
        let steps: Vec<StepFrame> = msgs
            .iter()
            .filter(|(s, _)| *s != 4)
            .map(|(_, m)| match m {
                Telemetry::Step(s) => *s,
                _ => unreachable!(),
            })
            .collect();
        let mut out = Vec::new();
        let stats = LinkStats {
            frames: 9,
            lost: 1,
            ..Default::default()
        };
        write_recording_csv(&mut out, &steps, 1e6, &[("mode", "dive".into())], &stats).unwrap();
        let text = String::from_utf8(out).unwrap();
        assert!(text.contains("# telemetry_frames_lost: 1"));
        assert!(text.contains("# telemetry_samples_missing: 1"));
        assert!(text.contains("# mode: dive"));
        // Header and one row per sample with its predecessor: 1, 2, 3, 6, 7, 8, 9 (not 0, 5).
        assert_eq!(text.lines().filter(|l| !l.starts_with('#')).count(), 1 + 7);
    }

    #[test]
    fn commands_are_numbered_and_decodable() {
        let mut out = Vec::new();
        let mut w = CommandWriter::new(&mut out);
        assert_eq!(w.send(&Command::Stop).unwrap(), 0);
        assert_eq!(w.send(&Command::Ping { nonce: 1 }).unwrap(), 1);
        let mut d = FrameDecoder::new();
        let got: Vec<_> = out.iter().filter_map(|&b| d.push::<Command>(b)).collect();
        assert_eq!(
            got,
            vec![Ok((0, Command::Stop)), Ok((1, Command::Ping { nonce: 1 }))]
        );
    }

    #[test]
    fn garbage_between_frames_is_counted() {
        let mut bytes = vec![0x13, 0x37, 0x00];
        bytes.extend(encode_stream(&[(
            0,
            Telemetry::Hello {
                protocol: PROTOCOL_VERSION,
                board: board::QEMU_MPS2_AN500,
                core: 0,
            },
        )]));
        let (got, stats) = decode_log(&bytes);
        assert_eq!(got.len(), 1);
        assert_eq!(stats.corrupted(), 1);
    }
}
