//! Builds the HD API stand-in for the tests: `standin/hd_standin.c` compiled with the system C
//! compiler into a shared library named `libHD.so`, the very name the OpenHaptics backend loads,
//! so the tests load it the way the vendor's library is loaded.
//!
//! Two variants, each in its own directory (the file name must stay `libHD.so`):
//! - `$OUT_DIR/standin/libHD.so`, the stand-in (`SOFTHAPTIC_HD_STANDIN`);
//! - `$OUT_DIR/standin-missing-symbol/libHD.so`, the same without `hdGetSchedulerTimeStamp`
//!   (`SOFTHAPTIC_HD_STANDIN_MISSING_SYMBOL`), for the backend's "a symbol is missing" error.
//!
//! The `cc` crate only finds the compiler and its target flags; the library is linked here,
//! because `cc` builds static archives and a library loaded at run time must be shared.

use std::path::{Path, PathBuf};

const SOURCE: &str = "standin/hd_standin.c";

fn main() {
    println!("cargo:rerun-if-changed={SOURCE}");
    let out_dir = PathBuf::from(std::env::var_os("OUT_DIR").expect("cargo sets OUT_DIR"));
    let source = Path::new(env!("CARGO_MANIFEST_DIR")).join(SOURCE);

    let standin = out_dir.join("standin").join("libHD.so");
    compile(&source, &standin, &[]);
    println!(
        "cargo:rustc-env=SOFTHAPTIC_HD_STANDIN={}",
        standin.display()
    );

    let missing = out_dir.join("standin-missing-symbol").join("libHD.so");
    compile(&source, &missing, &["-DSTANDIN_OMIT_TIMESTAMP"]);
    println!(
        "cargo:rustc-env=SOFTHAPTIC_HD_STANDIN_MISSING_SYMBOL={}",
        missing.display()
    );
}

/// Compiles `source` into the shared library `output`; a failure fails the build with the
/// compiler's output, and its warnings are passed on as cargo warnings.
fn compile(source: &Path, output: &Path, extra_flags: &[&str]) {
    if let Some(dir) = output.parent()
        && let Err(e) = std::fs::create_dir_all(dir)
    {
        panic!("could not create {}: {e}", dir.display());
    }
    let compiler = cc::Build::new().get_compiler();
    let mut command = compiler.to_command();
    command
        .args(["-std=c11", "-Wall", "-Wextra"])
        // Only the HD API and the stand-in's controls leave the library.
        .arg("-fvisibility=hidden")
        .args(["-shared", "-fPIC", "-O2", "-pthread"])
        // Never unmapped by dlclose: the scheduler thread may still be running its code when the
        // last handle is dropped, and the tests' and the backend's handles share its globals.
        .arg("-Wl,-z,nodelete")
        .args(extra_flags)
        .arg("-o")
        .arg(output)
        .arg(source)
        .arg("-lm");
    let result = match command.output() {
        Ok(result) => result,
        Err(e) => panic!(
            "could not run the C compiler {}: {e}",
            compiler.path().display()
        ),
    };
    let stdout = String::from_utf8_lossy(&result.stdout);
    let stderr = String::from_utf8_lossy(&result.stderr);
    if !result.status.success() {
        // The command line without the environment `Command`'s Debug would print.
        let line = std::iter::once(command.get_program())
            .chain(command.get_args())
            .map(|part| part.to_string_lossy())
            .collect::<Vec<_>>()
            .join(" ");
        panic!(
            "compiling the HD API stand-in into {} failed ({}):\n{line}\n{stdout}{stderr}",
            output.display(),
            result.status
        );
    }
    for line in stdout.lines().chain(stderr.lines()) {
        println!("cargo:warning={line}");
    }
}
