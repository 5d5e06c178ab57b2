//! `host-sim link`'s numeric flags are range-checked before a link is opened: a value out of
//! range is an error naming the flag (exit 1), never a panic (exit 101), and the controller is
//! never asked for anything (no controller listens on the address used here).
use std::process::Command;

fn link(args: &[&str]) -> (i32, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_host-sim"))
        .args(["link", "--tcp", "127.0.0.1:9"])
        .args(args)
        .output()
        .expect("host-sim runs");
    (
        out.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

#[test]
fn absurd_numbers_are_refused_by_flag_never_a_panic() {
    for (args, flag) in [
        (&["--timeout-s", "1e30", "status"][..], "--timeout-s"),
        (&["--timeout-s", "1e19", "status"][..], "--timeout-s"),
        (&["--timeout-s", "NaN", "status"][..], "--timeout-s"),
        (&["--timeout-s", "0", "status"][..], "--timeout-s"),
        (
            &["telemetry", "--seconds", "1e30", "--csv", "/tmp/never.csv"][..],
            "--seconds",
        ),
        (
            &["telemetry", "--seconds=-1", "--csv", "/tmp/never.csv"][..],
            "--seconds",
        ),
        (&["stream", "--cut-after", "0"][..], "--cut-after"),
        (&["stream", "--seconds", "1e9"][..], "--seconds"),
        (&["stream", "--freq-hz", "inf"][..], "--freq-hz"),
        (&["stream", "--amp-mm", "1e30", "0"][..], "--amp-mm"),
        (&["move", "--x-mm", "NaN", "--y-mm", "0"][..], "--x-mm"),
        (&["garbage", "--bytes", "0"][..], "--bytes"),
    ] {
        let (code, stderr) = link(args);
        assert_eq!(code, 1, "{args:?}: exit {code}\n{stderr}");
        assert!(stderr.contains(flag), "{args:?}: {stderr}");
        assert!(!stderr.contains("panicked"), "{args:?}: {stderr}");
    }
}
