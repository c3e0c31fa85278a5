//! A web console connection in memory, for picoserve: the request's bytes in, what the module
//! sent out. Used by the web tests (`services/web/tests/web.rs`) and the fuzz target `web_api`
//! (`#[path]`), so both drive the real router the same way.

use picoserve::io::Socket;
use picoserve::Timeouts;

/// The request's bytes (read in pieces of at most `piece` bytes: a request split across
/// reads), and what the module sent.
pub struct Connection<'a> {
    /// The request's bytes not yet read.
    pub input: &'a [u8],
    /// What the module sent.
    pub output: &'a mut Vec<u8>,
    /// The most bytes one read returns.
    pub piece: usize,
}

/// The connection's reading side.
pub struct Input<'a>(&'a [u8], usize);

impl embedded_io_async::ErrorType for Input<'_> {
    type Error = core::convert::Infallible;
}

impl embedded_io_async::Read for Input<'_> {
    async fn read(&mut self, buf: &mut [u8]) -> Result<usize, Self::Error> {
        let n = buf.len().min(self.0.len()).min(self.1);
        buf[..n].copy_from_slice(&self.0[..n]);
        self.0 = &self.0[n..];
        Ok(n)
    }
}

/// The connection's writing side.
pub struct Output<'a>(&'a mut Vec<u8>);

impl embedded_io_async::ErrorType for Output<'_> {
    type Error = core::convert::Infallible;
}

impl embedded_io_async::Write for Output<'_> {
    async fn write(&mut self, buf: &[u8]) -> Result<usize, Self::Error> {
        self.0.extend_from_slice(buf);
        Ok(buf.len())
    }

    async fn flush(&mut self) -> Result<(), Self::Error> {
        Ok(())
    }
}

impl picoserve::io::Write for Output<'_> {
    async fn write_with<F: FnOnce(picoserve::mem::BorrowedCursor<'_>) -> R, R>(
        &mut self,
        f: F,
    ) -> Result<R, Self::Error> {
        remodaq_web::service::write_with_buffer(self, f).await
    }
}

impl Socket<picoserve::EmbassyRuntime> for Connection<'_> {
    type Error = core::convert::Infallible;
    type ReadHalf<'a>
        = Input<'a>
    where
        Self: 'a;
    type WriteHalf<'a>
        = Output<'a>
    where
        Self: 'a;

    fn split(&mut self) -> (Self::ReadHalf<'_>, Self::WriteHalf<'_>) {
        (Input(self.input, self.piece), Output(self.output))
    }

    async fn abort<T: picoserve::time::Timer<picoserve::EmbassyRuntime>>(
        self,
        _: &Timeouts,
        _: &T,
    ) -> Result<(), picoserve::Error<Self::Error>> {
        Ok(())
    }

    async fn shutdown<T: picoserve::time::Timer<picoserve::EmbassyRuntime>>(
        self,
        _: &Timeouts,
        _: &T,
    ) -> Result<(), picoserve::Error<Self::Error>> {
        Ok(())
    }
}
