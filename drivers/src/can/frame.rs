//! Classic CAN frames and the frame-transport abstraction the CANopen driver runs on,
//! with a socketcand (TCP) backend used in tests and a SocketCAN backend for production.

use std::io;

use futures_util::{SinkExt, StreamExt};
use tokio::io::{AsyncRead, AsyncWrite};
use tokio::net::TcpStream;
use tokio_util::codec::Framed;

use super::socketcand::{SocketcandCodec, parse_frame, send_body};
use crate::link::BoxFuture;
use crate::tee::{Side, Tee};
use crate::transcript::Recorder;

/// One classic CAN data frame.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct CanFrame {
    /// 11-bit or 29-bit identifier.
    pub id: u32,
    /// True for a 29-bit identifier.
    pub extended: bool,
    /// 0 to 8 data bytes.
    pub data: Vec<u8>,
}

impl CanFrame {
    /// A standard-id frame.
    pub fn new(id: u16, data: &[u8]) -> Self {
        CanFrame {
            id: u32::from(id),
            extended: false,
            data: data.to_vec(),
        }
    }
}

/// Sends and receives CAN frames (one bus). Object safe.
pub trait FrameTransport: Send + 'static {
    /// Sends one frame.
    fn send(&mut self, f: CanFrame) -> BoxFuture<'_, io::Result<()>>;
    /// Receives the next frame from the bus.
    fn recv(&mut self) -> BoxFuture<'_, io::Result<CanFrame>>;
}

/// Opens a frame transport (reconnection point for the CANopen driver).
pub trait CanConnect: Send + 'static {
    /// The transport produced.
    type Bus: FrameTransport;
    /// Opens the bus.
    fn connect(&mut self) -> BoxFuture<'_, io::Result<Self::Bus>>;
}

fn proto(e: crate::error::CodecError) -> io::Error {
    match e {
        crate::error::CodecError::Io(e) => e,
        other => io::Error::new(io::ErrorKind::InvalidData, other.to_string()),
    }
}

/// socketcand client in raw mode over any byte stream.
#[derive(Debug)]
pub struct Socketcand<T> {
    framed: Framed<T, SocketcandCodec>,
}

impl<T: AsyncRead + AsyncWrite + Unpin + Send + 'static> Socketcand<T> {
    /// Performs the handshake (`< hi >`, `< open bus >`, `< ok >`, `< rawmode >`, `< ok >`).
    pub async fn open(io: T, bus: &str) -> io::Result<Self> {
        let mut framed = Framed::new(io, SocketcandCodec);
        let expect = async |f: &mut Framed<T, SocketcandCodec>, want: &str| -> io::Result<()> {
            match f.next().await {
                Some(Ok(w)) if w == [want] => Ok(()),
                Some(Ok(w)) => Err(io::Error::new(
                    io::ErrorKind::InvalidData,
                    format!("socketcand: expected < {want} >, got < {} >", w.join(" ")),
                )),
                Some(Err(e)) => Err(proto(e)),
                None => Err(io::ErrorKind::UnexpectedEof.into()),
            }
        };
        expect(&mut framed, "hi").await?;
        framed.send(format!("open {bus}")).await.map_err(proto)?;
        expect(&mut framed, "ok").await?;
        framed.send("rawmode".to_string()).await.map_err(proto)?;
        expect(&mut framed, "ok").await?;
        Ok(Socketcand { framed })
    }
}

impl<T: AsyncRead + AsyncWrite + Unpin + Send + 'static> FrameTransport for Socketcand<T> {
    fn send(&mut self, f: CanFrame) -> BoxFuture<'_, io::Result<()>> {
        Box::pin(async move { self.framed.send(send_body(&f)).await.map_err(proto) })
    }
    fn recv(&mut self) -> BoxFuture<'_, io::Result<CanFrame>> {
        Box::pin(async move {
            loop {
                match self.framed.next().await {
                    None => return Err(io::ErrorKind::UnexpectedEof.into()),
                    Some(Err(e)) => return Err(proto(e)),
                    Some(Ok(w)) if w.first().map(String::as_str) == Some("frame") => {
                        return parse_frame(&w).map_err(proto);
                    }
                    Some(Ok(w)) if w.first().map(String::as_str) == Some("error") => {
                        return Err(io::Error::other(format!("socketcand: < {} >", w.join(" "))));
                    }
                    Some(Ok(_)) => {}
                }
            }
        })
    }
}

/// Connects to a socketcand server over TCP and opens `bus` in raw mode.
#[derive(Debug, Clone)]
pub struct SocketcandConnector {
    /// `host:port` (socketcand default port 29536).
    pub addr: String,
    /// Bus name, e.g. `can0`.
    pub bus: String,
    /// Optional traffic recorder (socketcand text as bytes).
    pub recorder: Option<Recorder>,
}

impl CanConnect for SocketcandConnector {
    type Bus = Socketcand<Tee<TcpStream>>;
    fn connect(&mut self) -> BoxFuture<'_, io::Result<Self::Bus>> {
        Box::pin(async move {
            let s = TcpStream::connect(&self.addr).await?;
            s.set_nodelay(true)?;
            Socketcand::open(
                Tee::new(
                    s,
                    self.recorder.as_ref().map(Recorder::connection),
                    Side::Client,
                ),
                &self.bus,
            )
            .await
        })
    }
}

/// A SocketCAN interface (`can0`, `vcan0`) through the `socketcan` crate.
#[derive(Debug)]
pub struct SocketCanBus {
    sock: socketcan::tokio::CanSocket,
}

impl FrameTransport for SocketCanBus {
    fn send(&mut self, f: CanFrame) -> BoxFuture<'_, io::Result<()>> {
        Box::pin(async move {
            use socketcan::{EmbeddedFrame, ExtendedId, Id, StandardId};
            let id: Id = if f.extended {
                ExtendedId::new(f.id).map(Id::Extended)
            } else {
                u16::try_from(f.id)
                    .ok()
                    .and_then(StandardId::new)
                    .map(Id::Standard)
            }
            .ok_or_else(|| {
                io::Error::new(
                    io::ErrorKind::InvalidInput,
                    format!("bad CAN id {:#x}", f.id),
                )
            })?;
            let frame = socketcan::CanFrame::new(id, &f.data).ok_or_else(|| {
                io::Error::new(io::ErrorKind::InvalidInput, "more than 8 data bytes")
            })?;
            self.sock.write_frame(frame).await
        })
    }
    fn recv(&mut self) -> BoxFuture<'_, io::Result<CanFrame>> {
        Box::pin(async move {
            use socketcan::{EmbeddedFrame, Id};
            loop {
                let f = self.sock.read_frame().await?;
                if let socketcan::CanFrame::Data(d) = f {
                    let (id, extended) = match d.id() {
                        Id::Standard(s) => (u32::from(s.as_raw()), false),
                        Id::Extended(e) => (e.as_raw(), true),
                    };
                    return Ok(CanFrame {
                        id,
                        extended,
                        data: d.data().to_vec(),
                    });
                }
            }
        })
    }
}

/// Opens a SocketCAN interface by name (needs AF_CAN in the kernel).
#[derive(Debug, Clone)]
pub struct SocketCanConnector {
    /// Interface name, e.g. `can0`.
    pub iface: String,
}

impl CanConnect for SocketCanConnector {
    type Bus = SocketCanBus;
    fn connect(&mut self) -> BoxFuture<'_, io::Result<SocketCanBus>> {
        Box::pin(async move {
            Ok(SocketCanBus {
                sock: socketcan::tokio::CanSocket::open(&self.iface)?,
            })
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[tokio::test]
    #[ignore = "needs vcan (no AF_CAN in this kernel)"]
    async fn socketcan_loopback_on_vcan0() {
        let mut a = SocketCanConnector {
            iface: "vcan0".into(),
        }
        .connect()
        .await
        .unwrap();
        let mut b = SocketCanConnector {
            iface: "vcan0".into(),
        }
        .connect()
        .await
        .unwrap();
        a.send(CanFrame::new(0x601, &[0x40, 0x41, 0x60, 0, 0, 0, 0, 0]))
            .await
            .unwrap();
        assert_eq!(b.recv().await.unwrap().id, 0x601);
    }
}
