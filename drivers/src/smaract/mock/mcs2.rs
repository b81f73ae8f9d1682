//! The MCS2 mock's SCPI-like command set: queries answer one line, set commands and actions
//! are silent and report problems through the error queue (`:SYST:ERR?`).

use super::{Activity, Sim};

/// One MCS2 command; `Some(reply)` for queries.
pub(super) fn mcs2_reply(s: &mut Sim, cmd: &str) -> Option<String> {
    if cmd.is_empty() {
        return None;
    }
    let upper = cmd.to_ascii_uppercase();
    let (head, arg) = upper
        .split_once(' ')
        .map_or((upper.as_str(), ""), |(h, a)| (h, a.trim()));
    let num = |t: &str| t.trim().parse::<i64>().ok();
    let push = |s: &mut Sim, code: i64, text: &str| s.errors.push((code, text.to_string()));
    if head == ":SYST:ERR:COUN?" {
        return Some(s.errors.len().to_string());
    }
    if head == ":SYST:ERR?" || head == ":SYST:ERR:NEXT?" {
        return Some(if s.errors.is_empty() {
            "0,\"No error\"".into()
        } else {
            let (c, t) = s.errors.remove(0);
            format!("{c},\"{t}\"")
        });
    }
    if head == ":DEV:NOCH?" {
        return Some(s.axes.len().to_string());
    }
    if head == ":DEV:SNUM?" {
        return Some(super::MCS2_SERIAL.into());
    }
    if head == ":DEV:NAME?" {
        return Some(super::MCS2_NAME.into());
    }
    if head == ":DEV:STAT?" {
        return Some("0".into());
    }
    // :CHAN<ch>:... or :MOVE<ch> / :STOP<ch> / :REF<ch> / :CAL<ch>
    let (verb, ch_txt, tail) = if let Some(r) = head.strip_prefix(":CHAN") {
        let end = r.find(':').unwrap_or(r.len());
        ("CHAN", &r[..end], &r[end..])
    } else if let Some((v, r)) = [":MOVE", ":STOP", ":REF", ":CAL"]
        .iter()
        .find_map(|v| head.strip_prefix(v).map(|r| (*v, r)))
    {
        (v.trim_start_matches(':'), r, "")
    } else {
        push(s, -113, "Undefined header");
        return head.ends_with('?').then(|| "0".into());
    };
    let Some(ch) = s.channel(ch_txt) else {
        push(s, -222, "Data out of range: channel index");
        return head.ends_with('?').then(|| "0".into());
    };
    let a = s.axes[ch];
    let bits = {
        let mut b: i64 = (1 << 1) | (1 << 5) | (1 << 6) | (1 << 18);
        match a.activity {
            Activity::Moving { .. } => b |= 1,
            Activity::Referencing { .. } => b |= 1 | (1 << 3),
            Activity::Idle => b |= 1 << 19,
        }
        if a.referenced {
            b |= 1 << 7;
        }
        if a.fault {
            b |= 1 << 17;
        }
        b
    };
    match (verb, tail) {
        ("CHAN", ":POS?") => Some(a.pos.to_string()),
        ("CHAN", ":POS:TARG?") => Some(
            match a.activity {
                Activity::Moving { to, .. } => to,
                _ => a.pos,
            }
            .to_string(),
        ),
        ("CHAN", ":STAT?") => Some(bits.to_string()),
        ("CHAN", ":POS") => {
            match num(arg) {
                Some(v) => s.axes[ch].pos = v,
                None => push(s, -224, "Illegal parameter value"),
            }
            None
        }
        ("CHAN", ":MMOD")
        | ("CHAN", ":REF:OPT")
        | ("CHAN", ":VEL")
        | ("CHAN", ":ACC")
        | ("CHAN", ":HOLD")
        | ("CHAN", ":SENS:MODE")
        | ("CHAN", ":CAL:OPT") => {
            if num(arg).is_none() {
                push(s, -224, "Illegal parameter value");
            }
            None
        }
        ("MOVE", "") => {
            match num(arg) {
                Some(t) if a.fault => {
                    let _ = t;
                    push(s, -300, "Device-specific error: positioner fault");
                }
                Some(t) => {
                    if s.start_move(ch, t).is_err() {
                        push(s, -222, "Data out of range: range limit reached");
                    }
                }
                None => push(s, -224, "Illegal parameter value"),
            }
            None
        }
        ("STOP", "") => {
            s.stop(ch);
            None
        }
        ("REF", "") | ("CAL", "") => {
            s.start_reference(ch);
            None
        }
        _ => {
            push(s, -113, "Undefined header");
            head.ends_with('?').then(|| "0".into())
        }
    }
}
