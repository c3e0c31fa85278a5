//! Signing firmware images for the update service (`remodaq keygen`, `remodaq sign`): an
//! ed25519 signature over the image header (model, version, security counter, length and the
//! SHA-512 digest of the firmware bytes), as the module and its bootloader verify it
//! (docs/update.md). Keys are files of 64 hex digits: the secret key in `KEY`, the
//! public key in `KEY.pub` (what the firmware is built with).

use std::path::{Path, PathBuf};

use ed25519_dalek::{Signer, SigningKey};
use remodaq_client::Error;
use remodaq_protocol::update::{Header, Identity, IDENTITY_AT, SIGNED_LEN};
use sha2::{Digest, Sha512};

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

fn unhex32(text: &str, what: &Path) -> Result<[u8; 32], Error> {
    let text = text.trim();
    let bad = || Error::Other(format!("{}: not a key (64 hex digits)", what.display()));
    if text.len() != 64 {
        return Err(bad());
    }
    let mut out = [0u8; 32];
    for (i, byte) in out.iter_mut().enumerate() {
        *byte = u8::from_str_radix(&text[2 * i..2 * i + 2], 16).map_err(|_| bad())?;
    }
    Ok(out)
}

/// The public key file of a key file.
pub fn public_path(key: &Path) -> PathBuf {
    let mut name = key.as_os_str().to_owned();
    name.push(".pub");
    PathBuf::from(name)
}

/// `remodaq keygen`: a new key pair in `key` and `key.pub` (never overwrites).
pub fn keygen(key: &Path) -> Result<(), Error> {
    let public = public_path(key);
    for path in [key, public.as_path()] {
        if path.exists() {
            return Err(Error::Other(format!("{} exists: not overwritten", path.display())));
        }
    }
    let mut secret = [0u8; 32];
    getrandom::fill(&mut secret).map_err(|e| Error::Other(format!("no random numbers from the OS: {e}")))?;
    let signing = SigningKey::from_bytes(&secret);
    let write = |path: &Path, bytes: &[u8], secret: bool| {
        let fail = |e: std::io::Error| Error::Other(format!("cannot write {}: {e}", path.display()));
        let mut options = std::fs::OpenOptions::new();
        options.write(true).create_new(true);
        // The secret key readable and writable by its owner only (on Windows the file takes the
        // folder's permissions: keep it in a folder only you can read).
        #[cfg(unix)]
        if secret {
            use std::os::unix::fs::OpenOptionsExt;
            options.mode(0o600);
        }
        let _ = secret;
        let mut file = options.open(path).map_err(fail)?;
        std::io::Write::write_all(&mut file, format!("{}\n", hex(bytes)).as_bytes()).map_err(fail)
    };
    write(key, &secret, true)?;
    write(&public, signing.verifying_key().as_bytes(), false)?;
    println!(
        "secret key {} (keep it safe), public key {}: {}",
        key.display(),
        public.display(),
        hex(signing.verifying_key().as_bytes())
    );
    Ok(())
}

/// The image file of `firmware` for `model`, `version` and security `counter`, signed with
/// `key`.
pub fn image_file(firmware: &[u8], model: u16, version: u16, counter: u32, key: &SigningKey) -> Result<Vec<u8>, Error> {
    let length = u32::try_from(firmware.len()).map_err(|_| Error::Other("the firmware is too large".into()))?;
    let mut header =
        Header { model, version, counter, length, digest: Sha512::digest(firmware).into(), signature: [0; 64] };
    header.signature = key.sign(&header.encode()[..SIGNED_LEN]).to_bytes();
    Ok([&header.encode()[..], firmware].concat())
}

/// `remodaq sign`: writes the signed image file of a firmware binary, for the model and security
/// counter of the identity compiled into it (`Identity`, at `IDENTITY_AT`), which the bootloader
/// compares before a swap: `model` must be its model, and `counter`, when given, its counter.
pub fn sign(
    key: &Path,
    firmware: &Path,
    model: u16,
    version: u16,
    counter: Option<u32>,
    out: &Path,
) -> Result<(), Error> {
    let text = std::fs::read_to_string(key).map_err(|e| Error::Other(format!("cannot read {}: {e}", key.display())))?;
    let signing = SigningKey::from_bytes(&unhex32(&text, key)?);
    let bytes =
        std::fs::read(firmware).map_err(|e| Error::Other(format!("cannot read {}: {e}", firmware.display())))?;
    let identity = Identity::of_firmware(&bytes).ok_or_else(|| {
        Error::Other(format!(
            "{}: no image identity at {IDENTITY_AT:#x} (a raw binary of a RemoDAQ image of this release, \
             `llvm-objcopy -O binary`)",
            firmware.display()
        ))
    })?;
    if identity.model != model {
        return Err(Error::Other(format!(
            "{}: an image for the {:04X}, not the {model:04X}",
            firmware.display(),
            identity.model
        )));
    }
    let counter = counter.unwrap_or(identity.counter);
    if counter != identity.counter {
        return Err(Error::Other(format!(
            "{}: built with security counter {} (REMODAQ_SECURITY_COUNTER), not {counter}",
            firmware.display(),
            identity.counter
        )));
    }
    let file = image_file(&bytes, model, version, counter, &signing)?;
    std::fs::write(out, &file).map_err(|e| Error::Other(format!("cannot write {}: {e}", out.display())))?;
    println!(
        "{}: {} bytes of firmware for {model:04X}, version {version:04X}, security counter {counter}, signed for public key {}",
        out.display(),
        bytes.len(),
        hex(signing.verifying_key().as_bytes())
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use ed25519_dalek::VerifyingKey;

    use super::*;

    /// Whether an image file's signature is good for `public`.
    fn verify(file: &[u8], public: &VerifyingKey) -> bool {
        let Some((head, firmware)) = file.split_first_chunk::<{ remodaq_protocol::update::HEADER_LEN }>() else {
            return false;
        };
        let Some(header) = Header::decode(head) else { return false };
        let digest: [u8; 64] = Sha512::digest(firmware).into();
        // The module's own check (salty), and ed25519-dalek's strict one.
        firmware.len() == header.length as usize
            && header.verify(&digest, public.as_bytes())
            && public
                .verify_strict(&head[..SIGNED_LEN], &ed25519_dalek::Signature::from_bytes(&header.signature))
                .is_ok()
    }

    #[test]
    fn keygen_sign_and_verify() {
        let dir = std::env::temp_dir().join(format!("remodaq-sign-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let key = dir.join("vendor.key");
        keygen(&key).unwrap();
        assert!(keygen(&key).is_err(), "never overwrites a key");
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt;
            let mode = std::fs::metadata(&key).unwrap().permissions().mode() & 0o777;
            assert_eq!(mode, 0o600, "the secret key is its owner's only");
        }
        let firmware = dir.join("fw.bin");
        let mut bytes = (0..5000u32).map(|i| i as u8).collect::<Vec<_>>();
        std::fs::write(&firmware, &bytes).unwrap();
        let out = dir.join("fw.rdq");
        assert!(sign(&key, &firmware, 0x8350, 0xA101, Some(3), &out).is_err(), "no identity: not an image");
        let at = IDENTITY_AT as usize;
        bytes[at..at + 16].copy_from_slice(&Identity { model: 0x8350, counter: 3 }.encode());
        std::fs::write(&firmware, &bytes).unwrap();
        assert!(sign(&key, &firmware, 0x8318, 0xA101, Some(3), &out).is_err(), "another model's image");
        assert!(sign(&key, &firmware, 0x8350, 0xA101, Some(4), &out).is_err(), "another counter");
        assert!(!out.exists(), "nothing written for a refused image");
        sign(&key, &firmware, 0x8350, 0xA101, None, &out).unwrap();
        let file = std::fs::read(&out).unwrap();
        let public = unhex32(&std::fs::read_to_string(public_path(&key)).unwrap(), &key).unwrap();
        let public = VerifyingKey::from_bytes(&public).unwrap();
        assert!(verify(&file, &public));
        let header = Header::decode(file.first_chunk().unwrap()).unwrap();
        assert_eq!((header.model, header.version, header.counter, header.length), (0x8350, 0xA101, 3, 5000));
        let mut tampered = file.clone();
        tampered[200] ^= 1;
        assert!(!verify(&tampered, &public), "a changed byte of the firmware");
        // The header is signed: another model, version or counter breaks the signature.
        for at in [7, 9, 13] {
            let mut tampered = file.clone();
            tampered[at] ^= 1;
            assert!(!verify(&tampered, &public), "a changed header byte {at}");
        }
        let other = SigningKey::from_bytes(&[9; 32]).verifying_key();
        assert!(!verify(&file, &other), "another key");
        let _ = std::fs::remove_dir_all(&dir);
    }
}
