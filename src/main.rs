//! The `jetpilot` binary: parse the command line, set up logging, dispatch.

mod cli;

fn main() -> std::process::ExitCode {
    // burn builds a restored optimiser state on its default device before moving it to
    // the training device; unset, that default is the first GPU backend built in, which
    // may have no driver here. Flex is always there.
    #[cfg(feature = "train")]
    if std::env::var_os("BURN_DEVICE").is_none() {
        // SAFETY: the first statement of `main`: no other thread exists yet to read the
        // environment concurrently.
        unsafe { std::env::set_var("BURN_DEVICE", "flex") };
    }
    cli::main()
}
