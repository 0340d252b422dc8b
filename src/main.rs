//! The `r2human` command-line program: parses arguments and hands over to [`r2human::cli`].

fn main() -> std::process::ExitCode {
    r2human::cli::main()
}
