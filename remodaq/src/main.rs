//! `remodaq`: find RemoDAQ-8300 modules on the LAN, change their network settings, restart
//! and identify them, and read, watch and configure their I/O over Modbus/TCP.

mod io;
mod lan;
mod mqtt;
mod sign;
mod update;

use remodaq_client::Error;

use std::net::{Ipv4Addr, SocketAddr};
use std::process::ExitCode;
use std::time::Duration;

use clap::{Parser, Subcommand};

/// Find, configure, read and watch RemoDAQ-8318 and RemoDAQ-8350 modules.
#[derive(Parser)]
#[command(version, about, long_about = None)]
struct Cli {
    /// Machine-readable output (JSON) instead of tables.
    #[arg(long, global = true)]
    json: bool,
    /// Seconds to wait for answers.
    #[arg(long, global = true, default_value_t = 2.0)]
    timeout: f64,
    /// Search and configure through this interface of the PC only (its name, like `eth1`, or
    /// its address): by default a search goes out on every IPv4 interface that is up, and a
    /// command for a module by the interface it answered on.
    #[arg(long, global = true)]
    interface: Option<String>,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// List the modules that answer on the LAN.
    Search {
        /// Where to send the search: the broadcast address by default, or one module.
        #[arg(long, default_value = "255.255.255.255:8300")]
        to: SocketAddr,
    },
    /// Network settings.
    Net {
        #[command(subcommand)]
        command: NetCommand,
    },
    /// Restart a module (new network settings take effect).
    Restart {
        #[command(flatten)]
        target: Target,
        #[command(flatten)]
        password: Auth,
    },
    /// Blink a module's LED for 10 s.
    Identify {
        #[command(flatten)]
        target: Target,
    },
    /// Change a module's configuration password.
    Password {
        #[command(flatten)]
        target: Target,
        #[command(flatten)]
        password: Auth,
        /// The new password, at least 8 characters (asked for, without echo, when not given;
        /// or REMODAQ_NEW_PASSWORD). It never crosses the network: only keys derived from it.
        #[arg(long, env = "REMODAQ_NEW_PASSWORD", hide_env_values = true)]
        new: Option<String>,
    },
    /// Read a module's inputs and outputs once.
    Read {
        /// The module's Modbus/TCP address, e.g. 192.168.0.1 or 192.168.0.1:8000.
        module: String,
        #[command(flatten)]
        discovery: io::DiscoveryAt,
    },
    /// Read a module's inputs and outputs repeatedly.
    Watch {
        /// The module's Modbus/TCP address.
        module: String,
        #[command(flatten)]
        discovery: io::DiscoveryAt,
        /// Seconds between reads.
        #[arg(long, default_value_t = 1.0)]
        interval: f64,
        /// Stop after this many reads (default: until interrupted).
        #[arg(long)]
        count: Option<u64>,
    },
    /// Modbus write allow-list: which clients may write (05, 06, 15, 16). Reads are always
    /// served.
    Access {
        #[command(subcommand)]
        command: AccessCommand,
    },
    /// MQTT's settings (docs/mqtt.md), through the module's web console (a login with the
    /// configuration password; it never crosses the network).
    Mqtt {
        #[command(subcommand)]
        command: MqttCommand,
    },
    /// Update a module's firmware with a signed image file (remodaq sign), over the network:
    /// shows the progress and the version before and after.
    Update {
        /// The module's Modbus/TCP address (its version is read there).
        module: String,
        /// The signed image file.
        image: std::path::PathBuf,
        #[command(flatten)]
        password: Auth,
        /// The update service's TCP port.
        #[arg(long, default_value_t = remodaq_protocol::update::PORT)]
        port: u16,
        /// The module's MAC (as `remodaq search` shows it): the update goes on only if the
        /// module at MODULE is that one, and the proof of the password is bound to it.
        #[arg(long)]
        mac: Option<remodaq_client::lan::Mac>,
    },
    /// Make a key pair for signing firmware images: the secret key in KEY, the public key
    /// (what the firmware is built with) in KEY.pub.
    Keygen {
        /// The secret key file to create.
        key: std::path::PathBuf,
    },
    /// Sign a firmware binary for the update service: writes the image file.
    Sign {
        /// The secret key file (from `remodaq keygen`).
        #[arg(long)]
        key: std::path::PathBuf,
        /// The module the firmware is for: 8318 or 8350 (the model its identity names).
        #[arg(long, value_parser = hex16)]
        model: u16,
        /// The firmware version (register 40213), in hex, e.g. A101.
        #[arg(long, value_parser = hex16)]
        version: u16,
        /// The security counter (anti-rollback): a module refuses images below the highest
        /// counter it has confirmed, its bootloader images below the running one's. It is
        /// compiled into the image (`SECURITY_COUNTER`, or `REMODAQ_SECURITY_COUNTER` at build
        /// time); by default the image's, and when given it must be the image's.
        #[arg(long)]
        counter: Option<u32>,
        /// The firmware binary (the application image, as the bootloader starts it).
        firmware: std::path::PathBuf,
        /// The image file to write.
        #[arg(long)]
        out: std::path::PathBuf,
    },
    /// Configure a module's I/O (each maps to documented registers).
    Config {
        /// The module's Modbus/TCP address.
        module: String,
        #[command(subcommand)]
        setting: io::Setting,
    },
}

#[derive(Subcommand)]
enum NetCommand {
    /// Store new network settings (in force after `remodaq restart`). Every setting comes from
    /// the command line: nothing is taken from an unauthenticated search answer.
    Set {
        #[command(flatten)]
        target: Target,
        #[command(flatten)]
        password: Auth,
        /// IP address.
        #[arg(long)]
        ip: Ipv4Addr,
        /// Subnet mask.
        #[arg(long)]
        mask: Ipv4Addr,
        /// Default gateway (0.0.0.0: none).
        #[arg(long)]
        gateway: Ipv4Addr,
        /// Modbus/TCP port.
        #[arg(long, default_value_t = 8000)]
        port: u16,
    },
}

#[derive(Subcommand)]
enum AccessCommand {
    /// Show the allow-list.
    Show {
        #[command(flatten)]
        target: Target,
        #[command(flatten)]
        password: Auth,
    },
    /// Allow writes only from these networks (up to 4, CIDR form: 192.168.0.0/24; a bare
    /// address is /32). In force at once and kept across restarts.
    Set {
        #[command(flatten)]
        target: Target,
        #[command(flatten)]
        password: Auth,
        /// The networks.
        #[arg(required = true, num_args = 1..=4, value_parser = remodaq_client::lan::parse_cidr)]
        networks: Vec<remodaq_protocol::access::Network>,
    },
    /// Empty the allow-list: every client may write again (the factory setting).
    Clear {
        #[command(flatten)]
        target: Target,
        #[command(flatten)]
        password: Auth,
    },
}

#[derive(Subcommand)]
enum MqttCommand {
    /// Show MQTT's settings.
    Show {
        /// The module's web console: HOST (port 80) or HOST:PORT.
        module: String,
        #[command(flatten)]
        password: Auth,
    },
    /// Change MQTT's settings: those given, the others kept. In force at once, and kept across
    /// restarts. Not while the factory password is in force.
    Set {
        /// The module's web console: HOST (port 80) or HOST:PORT.
        module: String,
        #[command(flatten)]
        password: Auth,
        #[command(flatten)]
        changes: mqtt::Changes,
    },
}

/// A 16-bit value in hex (8350, A101, 0xA101).
fn hex16(s: &str) -> Result<u16, String> {
    u16::from_str_radix(s.trim_start_matches("0x").trim_start_matches("0X"), 16)
        .map_err(|_| format!("`{s}` is not 4 hex digits"))
}

/// Which module, by MAC address, and where to send the command.
#[derive(clap::Args)]
struct Target {
    /// The module's MAC address (as `remodaq search` shows it).
    #[arg(long)]
    mac: remodaq_client::lan::Mac,
    /// Where to send: the broadcast address by default (reaches modules on any subnet of the
    /// LAN), or the module's own address.
    #[arg(long, default_value = "255.255.255.255:8300")]
    to: SocketAddr,
}

/// The module's configuration password.
#[derive(clap::Args)]
struct Auth {
    /// Configuration password: asked for without echo when not given, or REMODAQ_PASSWORD for
    /// scripts (a password on the command line shows in the process list). It never crosses
    /// the network.
    #[arg(long, env = "REMODAQ_PASSWORD", hide_env_values = true)]
    password: Option<String>,
}

impl Auth {
    /// The password given, or asked for on the terminal.
    fn get(&self) -> Result<String, Error> {
        match &self.password {
            Some(p) => Ok(p.clone()),
            None => rpassword::prompt_password("configuration password: ").map_err(|e| {
                Error::Other(format!("no password given and none could be asked for ({e}): set REMODAQ_PASSWORD"))
            }),
        }
    }
}

/// A new password: given, or asked for twice; at least 8 characters, not the factory one.
fn new_password(given: Option<String>) -> Result<String, Error> {
    let new = match given {
        Some(p) => p,
        None => {
            let ask = |prompt: &str| {
                rpassword::prompt_password(prompt).map_err(|e| {
                    Error::Other(format!(
                        "no new password given and none could be asked for ({e}): set REMODAQ_NEW_PASSWORD"
                    ))
                })
            };
            let first = ask("new password: ")?;
            if ask("new password again: ")? != first {
                return Err(Error::Other("the two new passwords differ".into()));
            }
            first
        }
    };
    if new.chars().count() < remodaq_protocol::auth::MIN_PASSWORD_LEN {
        return Err(Error::Other(format!(
            "the new password is too short: at least {} characters",
            remodaq_protocol::auth::MIN_PASSWORD_LEN
        )));
    }
    if new == remodaq_protocol::auth::FACTORY_PASSWORD {
        return Err(Error::Other("the new password is the factory one".into()));
    }
    Ok(new)
}

fn main() -> ExitCode {
    // A test's aid (remodaq/tests/common): the file REMODAQ_START_MARKER names is created before
    // anything else, so that a run that ended without a word can be told from one that never
    // reached this program (a Windows loader failure under Wine).
    if let Some(marker) = std::env::var_os("REMODAQ_START_MARKER") {
        let _ = std::fs::write(marker, b"");
    }
    let cli = Cli::parse();
    let runtime = match tokio::runtime::Builder::new_current_thread().enable_all().build() {
        Ok(rt) => rt,
        Err(e) => {
            eprintln!("error: {e}");
            return ExitCode::from(1);
        }
    };
    match runtime.block_on(run(cli)) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::from(e.code())
        }
    }
}

async fn run(cli: Cli) -> Result<(), Error> {
    let timeout = Duration::from_secs_f64(cli.timeout.max(0.01));
    let json = cli.json;
    let only = cli.interface.as_deref();
    match cli.command {
        Command::Search { to } => lan::search(to, only, timeout, json).await,
        Command::Net { command: NetCommand::Set { target, password, ip, mask, gateway, port } } => {
            let change = remodaq_client::lan::NetChange { ip, mask, gateway, port };
            lan::set_network(target.to, only, target.mac, &password.get()?, change, timeout, json).await
        }
        Command::Restart { target, password } => {
            let password = password.get()?;
            lan::command(
                target.to,
                only,
                target.mac,
                Some(&password),
                remodaq_client::lan::Command::Restart,
                timeout,
                json,
            )
            .await
        }
        Command::Identify { target } => {
            lan::command(target.to, only, target.mac, None, remodaq_client::lan::Command::Identify, timeout, json).await
        }
        Command::Password { target, password, new } => {
            let password = password.get()?;
            let new = new_password(new)?;
            lan::command(
                target.to,
                only,
                target.mac,
                Some(&password),
                remodaq_client::lan::Command::SetPassword(&new),
                timeout,
                json,
            )
            .await
        }
        Command::Read { module, discovery } => io::read(&module, discovery, timeout, json).await,
        Command::Mqtt { command: MqttCommand::Show { module, password } } => {
            mqtt::show(&module, &password.get()?, json).await
        }
        Command::Mqtt { command: MqttCommand::Set { module, password, changes } } => {
            mqtt::set(&module, &password.get()?, &changes, json).await
        }
        Command::Watch { module, discovery, interval, count } => {
            let interval = Duration::from_secs_f64(interval.max(0.05));
            io::watch(&module, discovery, timeout, interval, count, json).await
        }
        Command::Access { command } => {
            let (target, password, cmd) = match &command {
                AccessCommand::Show { target, password } => (target, password, remodaq_client::lan::Command::GetAccess),
                AccessCommand::Set { target, password, networks } => {
                    let list = remodaq_protocol::access::AllowList::of(networks)
                        .ok_or_else(|| Error::Other("at most 4 networks".into()))?;
                    (target, password, remodaq_client::lan::Command::SetAccess(list))
                }
                AccessCommand::Clear { target, password } => (
                    target,
                    password,
                    remodaq_client::lan::Command::SetAccess(remodaq_protocol::access::AllowList::EMPTY),
                ),
            };
            let password = password.get()?;
            lan::command(target.to, only, target.mac, Some(&password), cmd, timeout, json).await
        }
        Command::Config { module, setting } => io::config(&module, setting, timeout, json).await,
        Command::Keygen { key } => sign::keygen(&key),
        Command::Update { module, image, password, port, mac } => {
            update::update(&module, mac, &image, &password.get()?, port, timeout, json).await
        }
        Command::Sign { key, model, version, counter, firmware, out } => {
            sign::sign(&key, &firmware, model, version, counter, &out)
        }
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn command_line_is_consistent() {
        <super::Cli as clap::CommandFactory>::command().debug_assert();
    }
}
