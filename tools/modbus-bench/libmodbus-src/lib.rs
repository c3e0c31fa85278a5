//! Empty: this package only fetches libmodbus-sys (see Cargo.toml).
