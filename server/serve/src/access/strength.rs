//! How many guesses a token given by a person would cost an attacker who knows how people make
//! them: an estimate in bits, from below, for refusing hand-made tokens at start.
//!
//! Length alone does not make a secret: `instructor-token-for-lab-2024xyz` is 32 characters,
//! but a guesser tries words, separators, years and runs like `xyz` long before random strings.
//! The estimate splits a token into pieces (runs of letters, a capitalised word counting as one;
//! runs of digits; single symbols) and prices each piece as a guesser would:
//!
//! - a piece that looks like a word (2 to 12 letters, lower case or capitalised, with vowels in
//!   a word's proportion and no longer consonant cluster than English has) as one of the few
//!   thousand words of its length: 8 to 15 bits however long it is;
//! - a year (`19xx`, `20xx`) 7 bits; a run of one character, or a sequence such as `abc` or
//!   `987`, the bits of its first character and its length;
//! - a piece seen before in the token 2 bits, the same symbol as the last one half a bit, another
//!   symbol 2 bits (a token's four symbols);
//! - anything else as random characters of the token's alphabet (hex digits 4 bits each,
//!   letters and digits of both cases about 6);
//!
//! and a token that repeats a shorter one is priced as that one. Each rule only lowers the
//! estimate below random characters', so a token drawn at random is priced near its true
//! entropy. Measured with this estimator over a million random tokens of each kind (the test
//! `estimates_of_random_tokens` repeats the hex case on twenty thousand): 32 hex digits (128
//! bits, `openssl rand -hex 16`) never below 85 bits, median 127; 32 base64url characters below
//! [`MIN_TOKEN_BITS`] 3 times in a million, 32 letters and digits 6 times, 32 lower-case letters
//! and digits 258 times (make those longer); the hand-made tokens of the tests 8 to 78 bits.

/// Fewest estimated bits a token given by a person may have: below every one of a million
/// tokens of `openssl rand -hex 16` (the least was 85), above the hand-made ones (78 the most).
pub const MIN_TOKEN_BITS: f64 = 80.0;

#[derive(Clone, Copy, PartialEq, Eq)]
enum Class {
    Lower,
    Upper,
    Digit,
    Symbol,
}

fn class(c: u8) -> Class {
    if c.is_ascii_lowercase() {
        Class::Lower
    } else if c.is_ascii_uppercase() {
        Class::Upper
    } else if c.is_ascii_digit() {
        Class::Digit
    } else {
        Class::Symbol
    }
}

/// Bits of one random character of the token's alphabet: the classes it uses, letters of one
/// case all within `a`–`f` counted as hex digits.
fn bits_per_character(token: &[u8]) -> f64 {
    let has = |k: Class| token.iter().any(|&c| class(c) == k);
    let (lower, upper) = (has(Class::Lower), has(Class::Upper));
    let hex_only = |range: std::ops::RangeInclusive<u8>| {
        token
            .iter()
            .filter(|&&c| c.is_ascii_alphabetic())
            .all(|c| range.contains(c))
    };
    let mut size = 0u32;
    if has(Class::Digit) {
        size += 10;
    }
    if lower {
        size += if !upper && hex_only(b'a'..=b'f') {
            6
        } else {
            26
        };
    }
    if upper {
        size += if !lower && hex_only(b'A'..=b'F') {
            6
        } else {
            26
        };
    }
    if has(Class::Symbol) {
        // A token's symbols are `-`, `.`, `_` and `~` (see `Token::parse`).
        size += 4;
    }
    f64::from(size.max(2)).log2()
}

/// The token's pieces: runs of lower-case letters (a capital before them included), of capitals,
/// of digits; each symbol alone.
fn pieces(token: &[u8]) -> Vec<&[u8]> {
    let mut out = Vec::new();
    let mut start = 0;
    for i in 1..=token.len() {
        let split = i == token.len()
            || !matches!(
                (class(token[i - 1]), class(token[i])),
                (Class::Upper | Class::Lower, Class::Lower)
                    | (Class::Upper, Class::Upper)
                    | (Class::Digit, Class::Digit)
            );
        if split {
            out.push(&token[start..i]);
            start = i;
        }
    }
    out
}

/// Whether `piece` could be a word: 2 to 12 letters, not all capitals (a random base32 string's
/// runs are), a quarter of them vowels (three tenths from five letters on: random letters have
/// about a fifth), no cluster of more than four consonants or three vowels.
fn looks_like_a_word(piece: &[u8]) -> bool {
    let vowel = |c: &u8| b"aeiouy".contains(&c.to_ascii_lowercase());
    if !(2..=12).contains(&piece.len())
        || !piece.iter().all(u8::is_ascii_alphabetic)
        || (piece.len() >= 3 && piece.iter().all(u8::is_ascii_uppercase))
    {
        return false;
    }
    let vowels = piece.iter().filter(|c| vowel(c)).count();
    if 4 * vowels < piece.len() || (piece.len() >= 5 && 10 * vowels < 3 * piece.len()) {
        return false;
    }
    let (mut consonant_run, mut vowel_run) = (0, 0);
    for c in piece {
        if vowel(c) {
            vowel_run += 1;
            consonant_run = 0;
        } else {
            consonant_run += 1;
            vowel_run = 0;
        }
        if consonant_run > 4 || vowel_run > 3 {
            return false;
        }
    }
    true
}

fn piece_bits(piece: &[u8], per_character: f64) -> f64 {
    let random = piece.len() as f64 * per_character;
    if let [only] = piece {
        return if class(*only) == Class::Symbol {
            2.0
        } else {
            per_character
        };
    }
    let length = piece.len() as f64;
    let step = i16::from(piece[1]) - i16::from(piece[0]);
    let sequence = piece.len() >= 3
        && step.abs() <= 1
        && piece
            .windows(2)
            .all(|w| i16::from(w[1]) - i16::from(w[0]) == step);
    if sequence {
        // Its first character, its length, its direction.
        return (per_character + length.log2() + 1.0).min(random);
    }
    if piece.len() == 4
        && piece.iter().all(u8::is_ascii_digit)
        && matches!(&piece[..2], b"19" | b"20")
    {
        return 7.0;
    }
    if looks_like_a_word(piece) {
        // Words of a length in a guesser's list (a few hundred of two letters, some ten
        // thousand of five and more), and one bit for a capital.
        let word: f64 = match piece.len() {
            2 => 7.0,
            3 => 10.0,
            4 => 12.0,
            _ => 14.0,
        };
        return (word + 1.0).min(random);
    }
    random
}

/// The estimated bits of `token` (its characters those `Token::parse` allows).
pub fn estimated_bits(token: &str) -> f64 {
    let bytes = token.as_bytes();
    // A token that repeats a shorter one: that one, and how many times.
    for period in 1..=bytes.len() / 2 {
        if (period..bytes.len()).all(|i| bytes[i] == bytes[i - period]) {
            return estimated_bits(&token[..period]) + (bytes.len() as f64 / period as f64).log2();
        }
    }
    let per_character = bits_per_character(bytes);
    let pieces = pieces(bytes);
    let mut bits = 0.0;
    let mut last_symbol = None;
    for (k, piece) in pieces.iter().enumerate() {
        let symbol = match piece {
            [c] if class(*c) == Class::Symbol => Some(*c),
            _ => None,
        };
        bits += if piece.len() >= 3 && pieces[..k].iter().any(|p| p.eq_ignore_ascii_case(piece)) {
            2.0
        } else if symbol.is_some() && symbol == last_symbol {
            0.5
        } else {
            piece_bits(piece, per_character)
        };
        if symbol.is_some() {
            last_symbol = symbol;
        }
    }
    bits
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hand_made_tokens_are_estimated_below_the_minimum() {
        for token in [
            "instructor-token-for-lab-2024xyz",
            "softhaptic-lab-instructor-secret-token",
            "lab2024-desk1-instructor-token-abc",
            "0123456789abcdef0123456789abcdef",
            "ffffffffffffffff0000000000000000",
            "abababababababababababababababab",
            "aaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaa",
            "abcdefghijklmnopqrstuvwxyz012345",
            "Tr0ub4dor.3Tr0ub4dor.3Tr0ub4dor.3",
            "observer-0123456789abcdef0123456789abcdef",
        ] {
            let bits = estimated_bits(token);
            assert!(bits < MIN_TOKEN_BITS, "{token}: {bits:.0} bits");
        }
    }

    #[test]
    fn random_tokens_of_the_usual_makers_pass() {
        for token in [
            // openssl rand -hex 16
            "5d41402abc4b2a76b9719d911017c592",
            "1f0e2d3c4b5a69788796a5b4c3d2e1f0",
            // uuidgen
            "550e8400-e29b-41d4-a716-446655440000",
            // openssl rand -base64 24 | tr '+/' '-_'
            "q3Vx-7ZkP0dWm_8RtYb2LhNc4JsEgAfU",
        ] {
            let bits = estimated_bits(token);
            assert!(bits >= MIN_TOKEN_BITS, "{token}: {bits:.0} bits");
        }
    }

    /// The figures of the module's comment, on a smaller sample (a test runs in well under a
    /// second): no generated-like hex token below the minimum.
    #[test]
    fn estimates_of_random_tokens() {
        let mut state = 0x9e37_79b9_7f4a_7c15_u64;
        let mut next = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            state
        };
        let mut lowest = f64::MAX;
        for _ in 0..20_000 {
            let token: String = (0..32)
                .map(|_| char::from(b"0123456789abcdef"[(next() % 16) as usize]))
                .collect();
            lowest = lowest.min(estimated_bits(&token));
        }
        assert!(lowest >= MIN_TOKEN_BITS + 4.0, "{lowest:.0} bits");
    }
}
