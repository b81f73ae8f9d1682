//! Who the CiA 402 driver talks to: device type (0x1000), the identity object 0x1018
//! (vendor id, product code, revision, serial) and the device name 0x1008 (a segmented
//! upload), plus the power state from the statusword.

use serde::Serialize;

use super::{Cia402Handle, DEVICE};
use crate::can::canopen::obj;
use crate::error::DriverError;
use crate::identity::Identity;

/// Identity of a CiA 402 drive.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct Cia402Identity {
    /// CANopen node id.
    pub node_id: u8,
    /// Device type (0x1000): low word the profile (402), high word the type.
    pub device_type: u32,
    /// Vendor id (0x1018:1).
    pub vendor_id: u32,
    /// Product code (0x1018:2).
    pub product_code: u32,
    /// Revision number (0x1018:3): major in the high word, minor in the low word.
    pub revision_number: u32,
    /// Serial number (0x1018:4; None when the drive does not have the entry).
    pub serial_number: Option<u32>,
    /// Manufacturer device name (0x1008; None when the drive does not have the object).
    pub device_name: Option<String>,
    /// Statusword (0x6041).
    pub statusword: u16,
    /// Power state decoded from the statusword.
    pub power_state: &'static str,
}

/// CiA 402 power state of a statusword (masks as in devices.md §5).
pub fn power_state(sw: u16) -> &'static str {
    if sw & 0x0008 != 0 {
        "fault"
    } else if sw & 0x4F == 0x40 {
        "switch on disabled"
    } else {
        match sw & 0x6F {
            0x21 => "ready to switch on",
            0x23 => "switched on",
            0x27 => "operation enabled",
            0x07 => "quick stop active",
            _ => "not ready to switch on",
        }
    }
}

impl Identity for Cia402Identity {
    const DEVICE_KIND: &'static str = DEVICE;

    fn fingerprint(&self) -> String {
        format!(
            "node {} type {:#010x} vendor {:#010x} product {:#010x} rev {:#010x} serial {:?} name {:?}",
            self.node_id,
            self.device_type,
            self.vendor_id,
            self.product_code,
            self.revision_number,
            self.serial_number,
            self.device_name
        )
    }

    fn summary(&self) -> String {
        format!(
            "node {} {:?}: vendor {:#010x} product {:#010x} rev {}.{}, {}",
            self.node_id,
            self.device_name.as_deref().unwrap_or("(no name)"),
            self.vendor_id,
            self.product_code,
            self.revision_number >> 16,
            self.revision_number & 0xFFFF,
            self.power_state
        )
    }

    fn problems(&self) -> Vec<String> {
        let mut p = Vec::new();
        if self.device_type & 0xFFFF != 402 {
            p.push(format!(
                "node {} is not a CiA 402 drive (device type {:#010x}): check the node id in the \
                 lab config",
                self.node_id, self.device_type
            ));
        }
        if self.power_state == "fault" {
            p.push(format!(
                "drive at node {} is in fault: read 0x603F, clear the cause and reset the fault",
                self.node_id
            ));
        }
        p
    }
}

/// An optional object: an SDO abort "object / sub-index does not exist" is None.
fn optional<T>(r: Result<T, DriverError>) -> Result<Option<T>, DriverError> {
    match r {
        Ok(v) => Ok(Some(v)),
        Err(DriverError::Device { code, .. }) if code == 0x0602_0000 || code == 0x0609_0011 => {
            Ok(None)
        }
        Err(e) => Err(e),
    }
}

impl Cia402Handle {
    async fn read_u32_sub(&self, index: u16, sub: u8) -> Result<u32, DriverError> {
        let d = self.read(index, sub).await?;
        d.get(..4)
            .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .ok_or_else(|| DriverError::Protocol {
                device: DEVICE,
                detail: format!("{index:#06x}:{sub} has {} bytes, expected 4", d.len()),
            })
    }

    /// Device type, identity object 0x1018, device name 0x1008 (segmented SDO upload) and
    /// the power state. The drive must answer 0x1000 and 0x1018:1-3 (mandatory in CiA 301);
    /// 0x1018:4 and 0x1008 are optional.
    pub async fn identity(&self) -> Result<Cia402Identity, DriverError> {
        let device_type = self.read_u32_sub(obj::DEVICE_TYPE, 0).await?;
        let vendor_id = self.read_u32_sub(obj::IDENTITY, 1).await?;
        let product_code = self.read_u32_sub(obj::IDENTITY, 2).await?;
        let revision_number = self.read_u32_sub(obj::IDENTITY, 3).await?;
        let serial_number = optional(self.read_u32_sub(obj::IDENTITY, 4).await)?;
        let device_name = optional(self.read(obj::DEVICE_NAME, 0).await)?.map(|b| {
            // VISIBLE_STRING; some drives pad with NULs.
            String::from_utf8_lossy(&b)
                .trim_end_matches('\0')
                .to_string()
        });
        let statusword = self.statusword().await?;
        Ok(Cia402Identity {
            node_id: self.cfg.node,
            device_type,
            vendor_id,
            product_code,
            revision_number,
            serial_number,
            device_name,
            statusword,
            power_state: power_state(statusword),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn power_states() {
        assert_eq!(power_state(0x0250), "switch on disabled");
        assert_eq!(power_state(0x0231), "ready to switch on");
        assert_eq!(power_state(0x0233), "switched on");
        assert_eq!(power_state(0x0237), "operation enabled");
        assert_eq!(power_state(0x0217), "quick stop active");
        assert_eq!(power_state(0x0218), "fault");
    }
}
