//! A scripted [`Link`] for driver unit tests, in the manner of embedded-hal-mock: the
//! test lists, in order, the exact bytes the driver must write and the bytes (or the
//! silence) the device answers with. A write that differs, a read nobody scripted, or
//! an expectation left unused when the mock is dropped fails the test.

use super::Link;
use std::collections::VecDeque;
use std::io::{self, Read, Write};
use std::time::Duration;

/// One step of the script.
#[derive(Clone, Debug, PartialEq)]
pub(crate) enum Step {
    /// The driver must write exactly these bytes (in one or several `write` calls).
    Tx(Vec<u8>),
    /// The device answers these bytes; reads take them, in as many calls as needed.
    Rx(Vec<u8>),
    /// The device stays silent: the next read fails with `TimedOut`.
    Silence,
}

/// `Step::Tx` from anything byte-like.
pub(crate) fn tx(bytes: impl AsRef<[u8]>) -> Step {
    Step::Tx(bytes.as_ref().to_vec())
}

/// `Step::Rx` from anything byte-like.
pub(crate) fn rx(bytes: impl AsRef<[u8]>) -> Step {
    Step::Rx(bytes.as_ref().to_vec())
}

/// The scripted link. Written bytes are matched against the script as they arrive.
#[derive(Debug)]
pub(crate) struct MockLink {
    script: VecDeque<Step>,
    /// Bytes of the current `Tx` step already written.
    written: usize,
    /// Last timeout the driver set, for tests that check it.
    pub timeout: Option<Duration>,
    /// How often the driver discarded pending input.
    pub(crate) discards: usize,
}

impl MockLink {
    pub(crate) fn new(script: impl IntoIterator<Item = Step>) -> MockLink {
        MockLink {
            script: script.into_iter().collect(),
            written: 0,
            timeout: None,
            discards: 0,
        }
    }

    /// Panics unless every step of the script was used.
    pub(crate) fn done(&mut self) {
        let left: Vec<Step> = self.script.drain(..).collect();
        assert!(left.is_empty(), "mock link: steps never used: {left:?}");
    }
}

impl Drop for MockLink {
    fn drop(&mut self) {
        if !std::thread::panicking() {
            self.done();
        }
    }
}

impl Read for MockLink {
    fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        match self.script.front_mut() {
            Some(Step::Rx(bytes)) => {
                let n = bytes.len().min(buf.len());
                buf[..n].copy_from_slice(&bytes[..n]);
                bytes.drain(..n);
                if bytes.is_empty() {
                    self.script.pop_front();
                }
                Ok(n)
            }
            Some(Step::Silence) => {
                self.script.pop_front();
                Err(io::ErrorKind::TimedOut.into())
            }
            other => panic!("mock link: driver read, but the script expects {other:?}"),
        }
    }
}

impl Write for MockLink {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        let mut done = 0;
        while done < buf.len() {
            let Some(Step::Tx(expected)) = self.script.front() else {
                panic!(
                    "mock link: driver wrote {:02X?}, but the script expects {:?}",
                    &buf[done..],
                    self.script.front()
                );
            };
            let want = &expected[self.written..];
            let n = want.len().min(buf.len() - done);
            assert_eq!(
                &buf[done..done + n],
                &want[..n],
                "mock link: driver wrote {:02X?} at offset {} of the expected {:02X?}",
                &buf[done..],
                self.written,
                expected
            );
            self.written += n;
            done += n;
            if self.written == expected.len() {
                self.script.pop_front();
                self.written = 0;
            }
        }
        Ok(done)
    }

    fn flush(&mut self) -> io::Result<()> {
        Ok(())
    }
}

impl Link for MockLink {
    fn set_timeout(&mut self, timeout: Duration) -> io::Result<()> {
        self.timeout = Some(timeout);
        Ok(())
    }

    fn discard_input(&mut self) -> io::Result<()> {
        self.discards += 1;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_script_played_in_full_passes() {
        let mut link = MockLink::new([tx(b"ab"), rx(b"xyz"), Step::Silence]);
        link.write_all(b"a").unwrap();
        link.write_all(b"b").unwrap();
        let mut buf = [0u8; 2];
        assert_eq!(link.read(&mut buf).unwrap(), 2);
        assert_eq!(link.read(&mut buf).unwrap(), 1);
        assert_eq!(&buf[..1], b"z");
        assert_eq!(
            link.read(&mut buf).unwrap_err().kind(),
            io::ErrorKind::TimedOut
        );
    }

    #[test]
    #[should_panic(expected = "steps never used")]
    fn an_unused_step_fails_on_drop() {
        let _link = MockLink::new([tx(b"ab")]);
    }

    #[test]
    #[should_panic(expected = "driver wrote")]
    fn a_wrong_byte_fails() {
        let mut link = MockLink::new([tx(b"ab")]);
        let _ = link.write(b"ax");
    }
}
