//! Device drivers for calibd: one async actor per device, transport-generic, with mock
//! servers that speak the same protocols.
