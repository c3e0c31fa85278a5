//! Modbus/TCP to a module (tokio-modbus): one connection, each request bounded by the timeout,
//! every failure in the error classes of [`crate::Error`].

use std::net::{SocketAddr, ToSocketAddrs};
use std::time::Duration;

use remodaq_protocol::{identity, m8318, m8350};
use tokio::time::timeout as within;
use tokio_modbus::client::{tcp, Client, Context};
use tokio_modbus::{ExceptionCode, Request, Response};

use crate::Error;

pub fn exception(e: ExceptionCode) -> Error {
    let meaning = match e {
        ExceptionCode::IllegalFunction => {
            "01 illegal function: the module does not support this request, or does not let this PC write (see `remodaq access`)"
        }
        ExceptionCode::IllegalDataAddress => "02 illegal data address: not mapped for this access on this module",
        ExceptionCode::IllegalDataValue => "03 illegal data value: the module does not accept this value",
        ExceptionCode::ServerDeviceFailure => {
            "04 server device failure: the setting could not be stored, or the outputs are held in the safe state (host watchdog tripped: `config MODULE watchdog clear`)"
        }
        _ => "unexpected exception",
    };
    Error::Exception(format!("the module answered exception {meaning}"))
}

/// A module's Modbus/TCP connection.
pub struct Module {
    ctx: Context,
    /// Its address.
    pub addr: SocketAddr,
    /// How long each request may take.
    pub timeout: Duration,
    /// Its model (40211): 0x8318 or 0x8350.
    pub model: u16,
}

pub fn resolve(module: &str) -> Result<SocketAddr, Error> {
    resolve_on(module, remodaq_protocol::MODBUS_PORT)
}

/// `module` as `HOST` (on `port`) or `HOST:PORT`.
pub fn resolve_on(module: &str, port: u16) -> Result<SocketAddr, Error> {
    let with_port = if module.contains(':') { module.to_string() } else { format!("{module}:{port}") };
    with_port
        .to_socket_addrs()
        .map_err(|e| Error::Other(format!("`{module}`: {e}")))?
        .next()
        .ok_or_else(|| Error::Other(format!("`{module}`: no address")))
}

impl Module {
    pub async fn connect(module: &str, timeout: Duration) -> Result<Self, Error> {
        let addr = resolve(module)?;
        let ctx = within(timeout, tcp::connect(addr))
            .await
            .map_err(|_| Error::Timeout(format!("no connection to {addr} within {:.1} s", timeout.as_secs_f64())))?
            .map_err(|e| Error::Other(format!("cannot connect to {addr}: {e}")))?;
        let mut m = Self { ctx, addr, timeout, model: 0 };
        m.model = m.reg(identity::REG_NAME).await?;
        if m.model != m8318::MODULE_NAME && m.model != m8350::MODULE_NAME {
            return Err(Error::Other(format!("{addr} is not a RemoDAQ-8318 or -8350 (40211 reads {:04X})", m.model)));
        }
        Ok(m)
    }

    pub fn late(&self) -> Error {
        Error::Timeout(format!("{} did not answer within {:.1} s", self.addr, self.timeout.as_secs_f64()))
    }

    /// The outcome of one request: no answer in time, a reply that does not fit it (another
    /// transaction or function, undecodable, the connection dropped), an exception, or the
    /// value.
    fn outcome<T>(&self, answer: Result<tokio_modbus::Result<T>, tokio::time::error::Elapsed>) -> Result<T, Error> {
        let reply = answer.map_err(|_| self.late())?;
        match reply {
            Ok(result) => result.map_err(exception),
            Err(tokio_modbus::Error::Protocol(e)) => Err(Error::Reply(format!("{}: {e}", self.addr))),
            Err(tokio_modbus::Error::Transport(e)) if e.kind() == std::io::ErrorKind::InvalidData => {
                Err(Error::Reply(format!("{}: not a Modbus/TCP reply ({e})", self.addr)))
            }
            Err(tokio_modbus::Error::Transport(e)) => Err(Error::Other(format!("{}: {e}", self.addr))),
        }
    }

    /// One request through tokio-modbus's checked `call` (it rejects another transaction or
    /// function); the caller checks that the response fits the request.
    pub async fn call(&mut self, request: Request<'_>) -> Result<Response, Error> {
        let answer = within(self.timeout, self.ctx.call(request)).await;
        self.outcome(answer)
    }

    pub fn misfit(&self, what: String) -> Error {
        Error::Reply(format!("{}: {what}", self.addr))
    }

    pub async fn regs(&mut self, addr: u16, n: u16) -> Result<Vec<u16>, Error> {
        match self.call(Request::ReadHoldingRegisters(addr, n)).await? {
            Response::ReadHoldingRegisters(words) if words.len() == usize::from(n) => Ok(words),
            Response::ReadHoldingRegisters(words) => {
                Err(self.misfit(format!("{} registers in the reply to a read of {n}", words.len())))
            }
            other => Err(self.misfit(format!("{other:?} in reply to a read of registers"))),
        }
    }

    pub async fn reg(&mut self, addr: u16) -> Result<u16, Error> {
        Ok(self.regs(addr, 1).await?[0])
    }

    pub async fn bits(&mut self, addr: u16, n: u16) -> Result<Vec<bool>, Error> {
        match self.call(Request::ReadCoils(addr, n)).await? {
            // Bits come in whole bytes: the reply carries up to 7 padding bits.
            Response::ReadCoils(mut bits) if bits.len() >= usize::from(n) && bits.len() < usize::from(n) + 8 => {
                bits.truncate(usize::from(n));
                Ok(bits)
            }
            Response::ReadCoils(bits) => Err(self.misfit(format!("{} bits in the reply to a read of {n}", bits.len()))),
            other => Err(self.misfit(format!("{other:?} in reply to a read of bits"))),
        }
    }

    pub async fn write_regs(&mut self, addr: u16, values: &[u16]) -> Result<(), Error> {
        let n = values.len() as u16;
        match self.call(Request::WriteMultipleRegisters(addr, values.into())).await? {
            Response::WriteMultipleRegisters(a, q) if (a, q) == (addr, n) => Ok(()),
            other => Err(self.misfit(format!("{other:?} in reply to a write of {n} registers at {addr:#06x}"))),
        }
    }

    pub async fn write_bit(&mut self, addr: u16, on: bool) -> Result<(), Error> {
        match self.call(Request::WriteSingleCoil(addr, on)).await? {
            Response::WriteSingleCoil(a, v) if (a, v) == (addr, on) => Ok(()),
            other => Err(self.misfit(format!("{other:?} in reply to a write of bit {addr:#06x}"))),
        }
    }

    pub fn expect(&self, model: u16) -> Result<(), Error> {
        if self.model == model {
            Ok(())
        } else {
            Err(Error::Other(format!(
                "this setting is for a RemoDAQ-{model:04X}; {} is a RemoDAQ-{:04X}",
                self.addr, self.model
            )))
        }
    }
}

/// The module name and firmware version registers of a module, and its address.
pub async fn identity(module: &str, timeout: Duration) -> Result<(SocketAddr, u16, u16), Error> {
    let mut m = Module::connect(module, timeout).await?;
    let version = m.reg(identity::REG_VERSION).await?;
    Ok((m.addr, m.model, version))
}
