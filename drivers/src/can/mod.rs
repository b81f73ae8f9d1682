//! CAN: classic frames, a frame-transport trait with socketcand (TCP) and SocketCAN
//! backends, CANopen SDO, the CiA 402 drive driver, and the socketcand hub mock with a
//! simulated drive.

pub mod canopen;
pub mod cia402;
pub mod frame;
pub mod mock;
pub mod node;
pub mod socketcand;

pub use cia402::{Cia402Config, Cia402Handle, Cia402Identity, Cia402State};
pub use frame::{
    CanConnect, CanFrame, FrameTransport, SocketCanConnector, Socketcand, SocketcandConnector,
};
