//! Consistent Overhead Byte Stuffing: removes every 0x00 from a frame so that 0x00 can mark
//! frame ends on a byte stream. Overhead is one byte per 254 and one at the start, so a
//! receiver that loses bytes resynchronises at the next 0x00 without any escape state.
//!
//! Every access is checked (`get`/`get_mut`), never indexed, so no input can panic: the
//! firmware decodes host commands with this code and links with a panic handler that fails
//! the link when reachable.

/// Why a COBS operation failed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CobsError {
    /// The output buffer is too small.
    Overflow,
    /// A 0x00 inside the encoded data (not allowed in COBS).
    ZeroByte,
    /// A block code points past the end of the data.
    Truncated,
}

/// The largest encoded size for `n` bytes of input (without the 0x00 delimiter).
pub const fn max_encoded_len(n: usize) -> usize {
    n + n / 254 + 1
}

/// Encodes `src` into `dst`, returning the encoded length (no trailing 0x00).
pub fn encode(src: &[u8], dst: &mut [u8]) -> Result<usize, CobsError> {
    let mut code_at = 0usize;
    let mut out = 1usize;
    let mut code: u8 = 1;
    for &b in src {
        if b == 0 {
            *dst.get_mut(code_at).ok_or(CobsError::Overflow)? = code;
            code_at = out;
            out += 1;
            code = 1;
        } else {
            *dst.get_mut(out).ok_or(CobsError::Overflow)? = b;
            out += 1;
            code += 1;
            if code == 0xFF {
                *dst.get_mut(code_at).ok_or(CobsError::Overflow)? = code;
                code_at = out;
                out += 1;
                code = 1;
            }
        }
    }
    *dst.get_mut(code_at).ok_or(CobsError::Overflow)? = code;
    Ok(out)
}

/// Decodes one COBS block sequence (without its 0x00 delimiter) into `dst`.
pub fn decode(src: &[u8], dst: &mut [u8]) -> Result<usize, CobsError> {
    let mut i = 0usize;
    let mut o = 0usize;
    while let Some(&code) = src.get(i) {
        if code == 0 {
            return Err(CobsError::ZeroByte);
        }
        i += 1;
        let n = (code - 1) as usize;
        let block = src
            .get(i..i.saturating_add(n))
            .ok_or(CobsError::Truncated)?;
        let out = dst
            .get_mut(o..o.saturating_add(n))
            .ok_or(CobsError::Overflow)?;
        // A zip, not `copy_from_slice`: the compiler cannot always prove the two lengths
        // equal, and `copy_from_slice` would then keep a panic path.
        for (d, &s) in out.iter_mut().zip(block) {
            if s == 0 {
                return Err(CobsError::ZeroByte);
            }
            *d = s;
        }
        o += n;
        i += n;
        if code != 0xFF && i < src.len() {
            *dst.get_mut(o).ok_or(CobsError::Overflow)? = 0;
            o += 1;
        }
    }
    Ok(o)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn roundtrip(data: &[u8]) {
        let mut enc = [0u8; 1200];
        let n = encode(data, &mut enc).unwrap();
        assert!(n <= max_encoded_len(data.len()));
        assert!(!enc[..n].contains(&0));
        let mut dec = [0u8; 1200];
        let m = decode(&enc[..n], &mut dec).unwrap();
        assert_eq!(&dec[..m], data);
    }

    #[test]
    fn known_vectors() {
        let mut enc = [0u8; 16];
        let n = encode(&[0x11, 0x22, 0x00, 0x33], &mut enc).unwrap();
        assert_eq!(&enc[..n], &[0x03, 0x11, 0x22, 0x02, 0x33]);
        let n = encode(&[0x00], &mut enc).unwrap();
        assert_eq!(&enc[..n], &[0x01, 0x01]);
        let n = encode(&[], &mut enc).unwrap();
        assert_eq!(&enc[..n], &[0x01]);
    }

    #[test]
    fn long_runs() {
        roundtrip(&[7u8; 254]);
        roundtrip(&[7u8; 255]);
        roundtrip(&[7u8; 600]);
        let mut v = [1u8; 600];
        v[253] = 0;
        v[254] = 0;
        roundtrip(&v);
    }

    #[test]
    fn small_output_is_an_error_not_a_panic() {
        let mut enc = [0u8; 3];
        assert_eq!(encode(&[1, 2, 3, 4], &mut enc), Err(CobsError::Overflow));
        let mut dec = [0u8; 1];
        assert_eq!(decode(&[0x03, 1, 2], &mut dec), Err(CobsError::Overflow));
        assert_eq!(decode(&[0x05, 1, 2], &mut dec), Err(CobsError::Truncated));
        assert_eq!(decode(&[0x02, 0], &mut dec), Err(CobsError::ZeroByte));
    }

    proptest! {
        #[test]
        fn prop_roundtrip(data in proptest::collection::vec(any::<u8>(), 0..1000)) {
            roundtrip(&data);
        }

        #[test]
        fn prop_decode_never_panics(data in proptest::collection::vec(any::<u8>(), 0..600)) {
            let mut dec = [0u8; 300];
            let _ = decode(&data, &mut dec);
        }
    }
}
