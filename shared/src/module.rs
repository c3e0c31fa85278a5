//! What every module's settings and register map offer to the common services (network
//! configuration and discovery): the network settings and the configuration password.

use crate::net::NetConfig;
use crate::password::PasswordHash;
use crate::settings::{Schema, StoreError};

/// Settings present in both modules.
pub trait CommonSettings: Schema + Copy {
    /// The stored network settings (in force after the next start).
    fn net(&self) -> NetConfig;
    /// Changes the stored network settings.
    fn set_net(&mut self, net: NetConfig);
    /// The configuration password.
    fn password(&self) -> PasswordHash;
    /// Changes the configuration password.
    fn set_password(&mut self, hash: PasswordHash);
}

/// Reading and committing a module's settings (implemented by its register map, which owns
/// the store).
#[allow(async_fn_in_trait)]
pub trait SettingsAccess {
    /// The module's settings.
    type Settings: CommonSettings;
    /// The settings in force.
    fn settings(&self) -> &Self::Settings;
    /// Commits new settings (durable when `Ok`), then puts them in force.
    async fn commit(&mut self, settings: Self::Settings) -> Result<(), StoreError>;
}

/// Implements [`CommonSettings`] for a settings struct with the fields `net: NetConfig` and
/// `password: PasswordHash`.
#[macro_export]
macro_rules! impl_common_settings {
    ($settings:ty) => {
        impl $crate::module::CommonSettings for $settings {
            fn net(&self) -> $crate::net::NetConfig {
                self.net
            }
            fn set_net(&mut self, net: $crate::net::NetConfig) {
                self.net = net;
            }
            fn password(&self) -> $crate::password::PasswordHash {
                self.password
            }
            fn set_password(&mut self, hash: $crate::password::PasswordHash) {
                self.password = hash;
            }
        }
    };
}
