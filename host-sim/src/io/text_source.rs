//! A text file read line by line, decoded and bounded: what a reader of a foreign file (an
//! instrument's export) streams through, and how every text file's encoding is judged.
//!
//! * **Encodings.** UTF-8 (a byte-order mark dropped); UTF-16 LE or BE, told by its byte-order
//!   mark or by the zero bytes of ASCII text, decoded; anything else that is not UTF-8 is read
//!   as Latin-1 (ISO 8859-1: every byte is a character, so nothing is lost; the first line that
//!   needed it is noted). Exports from Windows tools come in all three.
//! * **Bounds.** A line longer than [`MAX_LINE_BYTES`] or a file longer than the caller's limit
//!   is refused when the reader gets there, naming the line: a stream is never held whole, so
//!   a huge or hostile file costs no more memory than one line (UTF-16, rare, is decoded
//!   whole within the same limit).
//!
//! Why hand-rolled rather than a decoding crate: the three encodings instrument software
//! writes are a few lines with `std` (`String::from_utf16`, Latin-1 is byte = char), and the
//! bounds must be checked as bytes arrive, which a whole-file decoder would not do.

use super::IoError;
use std::io::{BufRead, BufReader, Read};
use std::path::Path;

/// The longest line read (bytes): far beyond any row of an export (a few hundred bytes).
pub const MAX_LINE_BYTES: usize = 64 * 1024;

/// How a file's bytes were decoded.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Encoding {
    Utf8,
    Utf16Le,
    Utf16Be,
    /// Not UTF-8: every byte read as its Latin-1 character.
    Latin1,
}

impl Encoding {
    /// The name in messages.
    pub fn name(self) -> &'static str {
        match self {
            Encoding::Utf8 => "UTF-8",
            Encoding::Utf16Le => "UTF-16 LE",
            Encoding::Utf16Be => "UTF-16 BE",
            Encoding::Latin1 => "Latin-1 (ISO 8859-1)",
        }
    }
}

/// The lines of a text, decoded (module doc).
pub struct TextLines {
    reader: Box<dyn BufRead>,
    /// The 1-based number of the last line returned.
    line: usize,
    bytes_read: u64,
    max_bytes: u64,
    what: String,
    /// How the text is decoded; `Latin1` once a line needed it.
    pub encoding: Encoding,
    /// The first line that was not UTF-8 (read as Latin-1).
    pub first_latin1_line: Option<usize>,
}

/// Detects UTF-16 from the first bytes: a byte-order mark, or ASCII's zero high bytes.
fn utf16(head: &[u8]) -> Option<(Encoding, usize)> {
    match head {
        [0xFF, 0xFE, ..] => Some((Encoding::Utf16Le, 2)),
        [0xFE, 0xFF, ..] => Some((Encoding::Utf16Be, 2)),
        [a, 0, b, 0, ..] if *a != 0 && *b != 0 => Some((Encoding::Utf16Le, 0)),
        [0, a, 0, b, ..] if *a != 0 && *b != 0 => Some((Encoding::Utf16Be, 0)),
        _ => None,
    }
}

impl TextLines {
    /// Opens `path` for reading at most `max_bytes` (refused beyond, naming the limit).
    pub fn open(path: &Path, max_bytes: u64) -> Result<TextLines, IoError> {
        let file = std::fs::File::open(path).map_err(|e| IoError::read(path, e))?;
        let what = path.display().to_string();
        if let Ok(m) = file.metadata() {
            if m.is_file() && m.len() > max_bytes {
                return Err(IoError::content(
                    path,
                    format!(
                        "the file is {} bytes; at most {max_bytes} are read (a measurement session's export is far smaller: is it the right file?)",
                        m.len()
                    ),
                ));
            }
        }
        Self::from_reader(Box::new(BufReader::new(file)), max_bytes, &what)
            .map_err(|e| IoError::content(path, e))
    }

    /// Lines of any reader (`what` names it in messages).
    pub fn from_reader(
        mut reader: Box<dyn BufRead>,
        max_bytes: u64,
        what: &str,
    ) -> Result<TextLines, IoError> {
        let head = reader
            .fill_buf()
            .map_err(|e| IoError::Parse(e.to_string()))?
            .to_vec();
        let mut encoding = Encoding::Utf8;
        if let Some((enc, bom)) = utf16(&head) {
            // Decoded whole, within the byte limit.
            let mut bytes = Vec::new();
            (&mut reader)
                .take(max_bytes + 1)
                .read_to_end(&mut bytes)
                .map_err(|e| IoError::Parse(e.to_string()))?;
            if bytes.len() as u64 > max_bytes {
                return Err(IoError::Parse(format!(
                    "the file is more than {max_bytes} bytes, the most that is read"
                )));
            }
            let units: Vec<u16> = bytes[bom..]
                .chunks(2)
                .map(|c| match (enc, c) {
                    (Encoding::Utf16Le, [a, b]) => u16::from_le_bytes([*a, *b]),
                    (_, [a, b]) => u16::from_be_bytes([*a, *b]),
                    _ => 0xFFFD,
                })
                .collect();
            let text = String::from_utf16(&units).map_err(|_| {
                IoError::Parse(format!(
                    "the file looks like {} (its first bytes) but is not valid {0}: save it as UTF-8",
                    enc.name()
                ))
            })?;
            encoding = enc;
            reader = Box::new(std::io::Cursor::new(text.into_bytes()));
        } else if head.starts_with(&[0xEF, 0xBB, 0xBF]) {
            reader.consume(3);
        }
        Ok(TextLines {
            reader,
            line: 0,
            bytes_read: 0,
            max_bytes,
            what: what.to_string(),
            encoding,
            first_latin1_line: None,
        })
    }

    /// What a reader should tell the user about the encoding, if anything.
    pub fn note(&self) -> Option<String> {
        match (self.encoding, self.first_latin1_line) {
            (Encoding::Utf16Le | Encoding::Utf16Be, _) => {
                Some(format!("{} file, decoded", self.encoding.name()))
            }
            (_, Some(line)) => Some(format!(
                "not UTF-8 from line {line} on: read as {}",
                Encoding::Latin1.name()
            )),
            _ => None,
        }
    }

    /// The next line (without its line ending) and its number.
    fn next_line(&mut self) -> Result<Option<(usize, String)>, IoError> {
        let mut buf = Vec::new();
        let mut limited = (&mut self.reader).take(MAX_LINE_BYTES as u64 + 1);
        let n = limited
            .read_until(b'\n', &mut buf)
            .map_err(|e| IoError::Parse(format!("{}: {e}", self.what)))?;
        if n == 0 {
            return Ok(None);
        }
        self.line += 1;
        self.bytes_read += n as u64;
        if buf.len() > MAX_LINE_BYTES && !buf.ends_with(b"\n") {
            return Err(IoError::Parse(format!(
                "line {}: longer than {MAX_LINE_BYTES} bytes, the longest line read (is it a text export?)",
                self.line
            )));
        }
        if self.bytes_read > self.max_bytes {
            return Err(IoError::Parse(format!(
                "line {}: the file goes on past {} bytes, the most that is read",
                self.line, self.max_bytes
            )));
        }
        while buf.last().is_some_and(|b| *b == b'\n' || *b == b'\r') {
            buf.pop();
        }
        let text = match String::from_utf8(buf) {
            Ok(s) => s,
            Err(e) => {
                if self.first_latin1_line.is_none() {
                    self.first_latin1_line = Some(self.line);
                }
                self.encoding = Encoding::Latin1;
                e.into_bytes().iter().map(|&b| char::from(b)).collect()
            }
        };
        Ok(Some((self.line, text)))
    }
}

impl Iterator for TextLines {
    type Item = Result<(usize, String), IoError>;

    fn next(&mut self) -> Option<Self::Item> {
        self.next_line().transpose()
    }
}

/// Why `bytes` is not UTF-8 text, naming the line and what the file looks like: for formats
/// the tools define (UTF-8), which are refused rather than guessed.
pub fn not_utf8(bytes: &[u8], e: &std::str::Utf8Error) -> String {
    let at = e.valid_up_to();
    let line = 1 + bytes[..at].iter().filter(|b| **b == b'\n').count();
    let looks = match utf16(bytes) {
        Some((enc, _)) => enc.name(),
        None => "Latin-1 or Windows-1252",
    };
    format!(
        "line {line}: not UTF-8 text (byte 0x{:02X}); the file looks like {looks}: save it as UTF-8",
        bytes[at]
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lines(bytes: &[u8], max: u64) -> (Vec<String>, Option<String>) {
        let mut t =
            TextLines::from_reader(Box::new(std::io::Cursor::new(bytes.to_vec())), max, "t")
                .unwrap();
        let v = t.by_ref().map(|l| l.unwrap().1).collect();
        (v, t.note())
    }

    #[test]
    fn encodings_are_decoded_and_noted() {
        let (v, note) = lines(b"\xEF\xBB\xBFPoint;X\r\nP1;2\n", 100);
        assert_eq!((v, note), (vec!["Point;X".into(), "P1;2".into()], None));
        let (v, note) = lines(b"Punkt;X [\xB5m]\nP1;2\n", 100);
        assert_eq!(v[0], "Punkt;X [µm]");
        assert_eq!(
            note.unwrap(),
            "not UTF-8 from line 1 on: read as Latin-1 (ISO 8859-1)"
        );
        let le: Vec<u8> = [0xFF, 0xFE]
            .into_iter()
            .chain("P;X\nP1;2\n".encode_utf16().flat_map(u16::to_le_bytes))
            .collect();
        let (v, note) = lines(&le, 100);
        assert_eq!(v, vec!["P;X".to_string(), "P1;2".into()]);
        assert_eq!(note.unwrap(), "UTF-16 LE file, decoded");
        let be: Vec<u8> = "P;X\n".encode_utf16().flat_map(u16::to_be_bytes).collect();
        assert_eq!(lines(&be, 100).0, vec!["P;X".to_string()]);
    }

    #[test]
    fn long_lines_and_files_are_refused_naming_the_line() {
        let mut t = TextLines::from_reader(
            Box::new(std::io::Cursor::new(b"a\nb\nc\nd\n".to_vec())),
            5,
            "t",
        )
        .unwrap();
        let e = t.find_map(Result::err).unwrap().to_string();
        assert!(e.contains("line 3: the file goes on past 5 bytes"), "{e}");
        let long = vec![b'x'; MAX_LINE_BYTES + 10];
        let mut t =
            TextLines::from_reader(Box::new(std::io::Cursor::new(long)), u64::MAX, "t").unwrap();
        let e = t.next().unwrap().unwrap_err().to_string();
        assert!(e.contains("line 1: longer than"), "{e}");
        let latin1 = [b"ok\nX [".as_slice(), &[0xB5], b"m]\n"].concat();
        let e = std::str::from_utf8(&latin1).unwrap_err();
        assert_eq!(
            not_utf8(&latin1, &e),
            "line 2: not UTF-8 text (byte 0xB5); the file looks like Latin-1 or Windows-1252: save it as UTF-8"
        );
    }
}
