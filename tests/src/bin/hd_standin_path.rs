//! Prints the path of the HD API stand-in (`libHD.so` built from `tests/standin/hd_standin.c`),
//! so that scripts (the viewer's browser tests) can start the server against it:
//! `SOFTHAPTIC_HD_LIBRARY="$(cargo run -q -p softhaptic-tests --bin hd-standin-path)" softhaptic ...`.

fn main() {
    println!("{}", softhaptic_tests::standin::standin_path().display());
}
