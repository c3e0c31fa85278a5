//! What `remodaq search` and the configuration commands print (the protocol itself is
//! `remodaq_client::lan`).

use std::net::SocketAddr;
use std::time::Duration;

use remodaq_client::lan::{self, cidr, factory_warning, merge, search_each, Command, Mac};
use remodaq_client::Error;

/// `remodaq search`.
pub async fn search(to: SocketAddr, only: Option<&str>, timeout: Duration, json: bool) -> Result<(), Error> {
    let (by_interface, interfaces) = search_each(to, only, timeout, None).await?;
    let found = merge(by_interface);
    if json {
        println!("{}", serde_json::to_string_pretty(&found).unwrap_or_default());
        return Ok(());
    }
    // Where the search went, and what answered on each interface.
    let searched: Vec<String> = interfaces
        .iter()
        .flatten()
        .map(|i| {
            let n = found.iter().filter(|f| f.interface.as_deref() == Some(&i.label())).count();
            format!("{} {n}", i.label())
        })
        .collect();
    if !searched.is_empty() {
        println!("searched on {}: modules found {}", searched.len(), searched.join(", "));
    }
    if found.is_empty() {
        println!("no module answered within {:.1} s", timeout.as_secs_f64());
        return Ok(());
    }
    println!(
        "{:<14} {:<18} {:<16} {:<16} {:<16} {:>6} {:>9}",
        "model", "mac", "ip", "mask", "gateway", "port", "uptime"
    );
    // Grouped by the interface they answered on, as the manuals' tree shows them under
    // `Host (address)`.
    let mut found = found;
    found.sort_by(|a, b| a.interface.cmp(&b.interface));
    let mut host = None;
    for f in &found {
        if f.interface.is_some() && f.interface != host {
            host = f.interface.clone();
            println!("host {}", host.as_deref().unwrap_or_default());
        }
        let r = f.running;
        println!(
            "{:<14} {:<18} {:<16} {:<16} {:<16} {:>6} {:>8}s",
            f.name, f.mac, r.ip, r.mask, r.gateway, r.port, f.uptime_s
        );
        if f.factory_password {
            if let Ok(mac) = f.mac.parse() {
                println!("  {}", factory_warning(mac));
            }
        }
        if f.stored != f.running {
            let s = f.stored;
            println!(
                "{:<14} {:<18} {:<16} {:<16} {:<16} {:>6}   (stored: after a restart)",
                "", "", s.ip, s.mask, s.gateway, s.port
            );
        }
    }
    Ok(())
}

/// `remodaq net set`.
#[allow(clippy::too_many_arguments)]
pub async fn set_network(
    to: SocketAddr,
    only: Option<&str>,
    mac: Mac,
    password: &str,
    change: lan::NetChange,
    timeout: Duration,
    json: bool,
) -> Result<(), Error> {
    let outcome = lan::set_network(to, only, mac, password, change, timeout).await?;
    print(mac, lan::SET_NETWORK_DONE, false, &outcome, json);
    Ok(())
}

/// Sends a configuration command and prints its result.
pub async fn command(
    to: SocketAddr,
    only: Option<&str>,
    mac: Mac,
    password: Option<&str>,
    cmd: Command<'_>,
    timeout: Duration,
    json: bool,
) -> Result<(), Error> {
    let what = cmd.done();
    let set_password = matches!(cmd, Command::SetPassword(_));
    let outcome = lan::command(to, only, mac, password, cmd, timeout).await?;
    print(mac, what, set_password, &outcome, json);
    Ok(())
}

/// A configuration command's result: `what` it did, or the allow-list it read or stored.
fn print(mac: Mac, what: &str, set_password: bool, outcome: &lan::Outcome, json: bool) {
    if let Some(list) = outcome.list {
        let nets: Vec<String> = list.iter().map(cidr).collect();
        if json {
            let out = serde_json::json!({ "mac": mac.to_string(), "restricted": !list.is_empty(), "allow": nets });
            println!("{out}");
        } else if nets.is_empty() {
            println!("{mac}: Modbus writes allowed from any client (allow-list empty)");
        } else {
            println!("{mac}: Modbus writes allowed only from {}", nets.join(", "));
        }
    } else if json {
        println!("{}", serde_json::json!({ "mac": mac.to_string(), "status": "ok", "message": what }));
    } else {
        println!("{mac}: {what}");
    }
    if outcome.factory_password && !set_password && !json {
        println!("{}", factory_warning(mac));
    }
    if outcome.broadcast {
        eprintln!("{}", lan::broadcast_note(mac));
    }
}
