//! CAN buses behind serial-line adapters that speak SLCAN (the Lawicel protocol): one
//! port carries every frame of a bus. [`proto`] is the protocol on bytes alone; the link
//! that opens the adapter, sets its bitrate and reads the bus for many devices comes
//! with the engine's bus reader.

pub mod proto;
