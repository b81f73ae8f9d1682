//! `Tee`: wraps any byte stream and copies everything read and written to a [`Recorder`],
//! so every driver (and mock) can record a lab session as a transcript.

use std::io;
use std::pin::Pin;
use std::task::{Context, Poll};

use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};

use crate::transcript::{Direction, Recorder};

/// Which end of the conversation the wrapped stream is on.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Side {
    /// The driver: writes go to the device.
    Client,
    /// The (mock) device: writes go to the client.
    Device,
}

/// A byte stream that records its traffic when given a recorder (transparent otherwise).
#[derive(Debug)]
pub struct Tee<T> {
    inner: T,
    recorder: Option<Recorder>,
    side: Side,
}

impl<T> Tee<T> {
    /// Wraps `inner`; `recorder = None` records nothing.
    pub fn new(inner: T, recorder: Option<Recorder>, side: Side) -> Self {
        Tee {
            inner,
            recorder,
            side,
        }
    }

    /// The wrapped stream.
    pub fn get_ref(&self) -> &T {
        &self.inner
    }

    fn dir(&self, writing: bool) -> Direction {
        match (self.side, writing) {
            (Side::Client, true) | (Side::Device, false) => Direction::ToDevice,
            _ => Direction::FromDevice,
        }
    }
}

impl<T: AsyncRead + Unpin> AsyncRead for Tee<T> {
    fn poll_read(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<io::Result<()>> {
        let before = buf.filled().len();
        let r = Pin::new(&mut self.inner).poll_read(cx, buf);
        if let (Poll::Ready(Ok(())), Some(rec)) = (&r, &self.recorder) {
            rec.record(self.dir(false), &buf.filled()[before..], false);
        }
        r
    }
}

impl<T: AsyncWrite + Unpin> AsyncWrite for Tee<T> {
    fn poll_write(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &[u8],
    ) -> Poll<io::Result<usize>> {
        let r = Pin::new(&mut self.inner).poll_write(cx, buf);
        if let (Poll::Ready(Ok(n)), Some(rec)) = (&r, &self.recorder) {
            rec.record(self.dir(true), &buf[..*n], false);
        }
        r
    }

    fn poll_flush(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.inner).poll_flush(cx)
    }

    fn poll_shutdown(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.inner).poll_shutdown(cx)
    }
}
