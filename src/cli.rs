//! The command line: `adrive [run]` (the console), `adrive sim`, `adrive send`,
//! `adrive watch`, `adrive fleet`, `adrive replay`, `adrive record info`, `adrive export`, and
//! `adrive completions` / `adrive manpage`, generated from the same definitions.
//! Parsing is clap's; each subcommand is one function here that wires the parts
//! together.

use crate::config::{self, VehicleConfig};
use crate::engine::Engine;
use crate::engine::Gate;
use crate::exit::{self, Exit};
use crate::net::{auth::Auth, client, Net};
use crate::record::{self, Recorder};
use crate::sim::{Sim, SimEvent};
use crate::threads::Shutdown;
use crate::vehicle::Vehicle;
use crate::{console, driver, headless, logging, paths, socket};
use clap::{Args, CommandFactory, Parser, Subcommand};
use std::io::{self, BufRead, Write};
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;
use std::sync::Arc;
use std::time::{Duration, Instant};

#[derive(Parser, Debug)]
#[command(
    name = "adrive",
    version,
    about = "Drive-by-wire actuator engine with a Sparrow-style operator console"
)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Option<Cmd>,
    #[command(flatten)]
    pub run: RunArgs,
}

// Parsed once per process: the size of its largest variant costs nothing.
#[allow(clippy::large_enum_variant)]
#[derive(Subcommand, Debug)]
pub enum Cmd {
    /// Run the engine with the console (the default).
    Run(RunArgs),
    /// Run the simulated devices alone and print their port paths.
    Sim(SimArgs),
    /// List serial ports with what the OS knows of each.
    Ports,
    /// Send commands to a running adrive, once or repeatedly, as a planner would.
    ///
    /// Exit status: 0 sent and nothing refused; 1 something refused, or nothing
    /// listening (with --rate: at its end — refused in its last three periods, or 60 ms
    /// — or the last datagram found nothing listening); 2 a bad command line; 3 an
    /// engage, disengage, release or clear got no reply.
    Send(SendArgs),
    /// Print the state broadcast as it arrives.
    Watch(WatchArgs),
    /// Every vehicle on the fleet's Zenoh network: there or gone, engaged or not and
    /// why, who commands, its faults, how old its last state is (built with the cargo
    /// feature `fleet`).
    Fleet(FleetArgs),
    /// The console on a running adrive (a service, or another console's session), over
    /// its control socket: watching until it engages or takes command.
    ///
    /// Exit status: 0 the operator quit; 1 no adrive at the socket, or it went away;
    /// 129 the terminal hung up.
    Attach(AttachArgs),
    /// One operator command to a running adrive over its control socket, for scripts
    /// and for a person without a terminal.
    ///
    /// Exit status: 0 done; 1 refused, or no adrive at the socket; 3 no reply.
    Ctl(CtlArgs),
    /// Measure a setpoint actuator at the bench — delay, slew rates, step response,
    /// deadband, backlash, static map, repeatability, noise — and write its figures,
    /// samples, a report and the `[device.sim]` that makes the simulator behave like it.
    ///
    /// It commands on its own, after the operator confirms, only while the vehicle is
    /// stopped, in park, with the brake held (or on a bench where nothing else is
    /// bound: --only DEVICE), and ends at once, the device safe, on STOP, a fault, an
    /// override, a broken precondition or a signal.
    ///
    /// Exit status: 0 measured and written; 1 ended before it was done, or refused
    /// (nothing written); 2 a bad command line or vehicle file; 3 the safe state was
    /// not acknowledged.
    Characterize(CharacterizeArgs),
    /// Play a recording in the console: pause, step, seek, speed; read-only.
    Replay(ReplayArgs),
    /// Recordings: `adrive record info FILE`, `adrive record repair FILE`.
    Record {
        #[command(subcommand)]
        command: RecordCmd,
    },
    /// Write a recording out as one CSV file per channel.
    Export(ExportArgs),
    /// Print a shell completion script (see docs/commands.md for where each shell wants it).
    Completions {
        /// The shell to complete in.
        shell: clap_complete::Shell,
    },
    /// Print the manual page (roff), or write every page into a directory with --dir.
    Manpage {
        /// Write adrive.1 and a page per subcommand (adrive-send.1, …) into this directory
        /// instead, e.g. ~/.local/share/man/man1.
        #[arg(long, value_name = "DIR")]
        dir: Option<PathBuf>,
    },
}

/// The vehicle a run drives: its file, simulated or on its ports, whole or some of its
/// devices (`adrive`, `adrive serve`, `adrive characterize`).
#[derive(Args, Debug, Clone, Default)]
pub struct VehicleArgs {
    /// Vehicle TOML (default: the built-in simulated Alice).
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,
    /// Simulate every device on pseudo-terminals.
    #[arg(long)]
    pub sim: bool,
    /// Run just these devices (repeatable, or comma-separated), for the bench.
    #[arg(long, value_name = "NAME", value_delimiter = ',')]
    pub only: Vec<String>,
}

impl VehicleArgs {
    /// The vehicle file (or Alice) narrowed to `--only`, its ports' paths checked
    /// unless simulated.
    fn load(&self) -> anyhow::Result<VehicleConfig> {
        let config = load(&self.config, &self.only)?;
        if !self.sim {
            config.check_ports()?;
        }
        Ok(config)
    }

    /// Every device's port opened and locked ([`open_ports`]); none when simulated.
    fn open_ports(
        &self,
        config: &VehicleConfig,
    ) -> anyhow::Result<std::collections::HashMap<String, Box<dyn driver::Link>>> {
        if self.sim {
            Ok(std::collections::HashMap::new())
        } else {
            open_ports(config)
        }
    }
}

#[derive(Args, Debug, Clone, Default)]
pub struct RunArgs {
    #[command(flatten)]
    pub vehicle: VehicleArgs,
    /// No console: log and keep figures only; SIGINT/SIGTERM stop safely.
    #[arg(long)]
    pub headless: bool,
    /// Keymap TOML merged over the built-in one (default: ~/.config/adrive/keymap.toml if present).
    #[arg(long, value_name = "FILE")]
    pub keymap: Option<PathBuf>,
    /// Teleop deadman: with no teleop key for this long, gas goes to 0 and the brake on
    /// (100ms to 5s) [default: 1s].
    #[arg(long, value_name = "DURATION", value_parser = config::limits::parse_deadman)]
    pub deadman: Option<Duration>,
    /// A console that commands and whose terminal answers no round trip for this long
    /// (a stalled SSH link, a frozen client) stops the vehicle, embedded or attached
    /// (500ms to 10s) [default: the vehicle file's `[console]` terminal_timeout, 1s].
    #[arg(long, value_name = "DURATION", value_parser = config::limits::parse_terminal_timeout)]
    pub terminal_timeout: Option<Duration>,
    /// End the run (status 4, after the safe state) once a device has been gone this
    /// long, or a recovery procedure gave up after trying this long (1s to 1 day;
    /// default: never: adrive keeps the vehicle safe and waits for the device), instead
    /// of the vehicle file's `[supervisor]` give_up_after.
    #[arg(long, value_name = "DURATION", value_parser = config::limits::parse_give_up_after)]
    pub give_up_after: Option<Duration>,
    /// Fault injection for tests: make a thread panic once running, `main`,
    /// `supervisor` or a device's status thread (`steer/status`; `steer/status=return`
    /// ends it quietly instead), optionally after a delay (`supervisor:4s`).
    #[arg(long, value_name = "THREAD[:DELAY]", hide = true)]
    pub(crate) inject_panic: Option<String>,
    /// Fault injection for tests: make an engine thread (`steer/status`, `brake/command`,
    /// `bus/kit`, `gate/monitor`, `supervisor`) block in a system call once, AFTER its
    /// start, for FOR (`steer/status:2s:5s`), as a port stuck in the kernel would.
    #[arg(long, value_name = "THREAD:AFTER:FOR", hide = true)]
    pub(crate) inject_hang: Option<String>,
    /// Directory of the rolling log file (default: $XDG_STATE_HOME/adrive or ~/.local/state/adrive).
    #[arg(long, value_name = "DIR")]
    pub log_dir: Option<PathBuf>,
    /// Where the command listener binds, e.g. 0.0.0.0:47576 to take commands from other
    /// hosts (default: the vehicle file's `[network]` listen, 127.0.0.1:47576).
    #[arg(long, value_name = "ADDR", value_parser = config::network::parse_listen)]
    pub listen: Option<SocketAddr>,
    /// Where the state broadcast goes, instead of the vehicle file's `[network]`
    /// broadcast_to (repeatable, or comma-separated; default 127.0.0.1:47577): a
    /// second adrive on one host needs its own.
    #[arg(long, value_name = "ADDR", value_delimiter = ',', value_parser = config::network::parse_destination)]
    pub broadcast_to: Vec<SocketAddr>,
    /// Record this run into an MCAP file (Foxglove opens it), or into rolling files in
    /// a directory (an existing one, or a path ending in `/`); default: the vehicle
    /// file's `[record]`.
    #[arg(long, value_name = "FILE.mcap")]
    pub record: Option<PathBuf>,
    /// Record the raw serial traffic of every device too.
    #[arg(long)]
    pub(crate) record_raw: bool,
    /// Join the ROS 2 graph over Zenoh as an Autoware vehicle interface (the vehicle
    /// file's `[ros2]`; built with the cargo feature `ros2`).
    #[arg(long)]
    pub ros2: bool,
    /// Join a fleet over Zenoh as ID (default: the vehicle file's `[fleet]` id, else
    /// the vehicle's name in lower case): announce the vehicle and publish its state
    /// under `adrive/ID` (built with the cargo feature `fleet`). A `[fleet]` section
    /// in the vehicle file joins without this flag.
    #[arg(long, value_name = "ID", num_args = 0..=1, default_missing_value = "")]
    pub fleet: Option<String>,
    /// The fleet's Zenoh router (or a peer) to connect to, instead of the vehicle
    /// file's `[fleet]` connect (repeatable, or comma-separated; default
    /// tcp/localhost:7447).
    #[arg(long, value_name = "ENDPOINT", value_delimiter = ',')]
    pub fleet_connect: Vec<String>,
    /// Serve a read-only live view to Foxglove or Lichtblick (Foxglove WebSocket
    /// protocol) on ADDR [default: 127.0.0.1:8765; port 0: any free port, logged].
    #[arg(long, value_name = "ADDR", num_args = 0..=1, default_missing_value = crate::foxglove::DEFAULT_ADDR, value_parser = config::network::parse_serve)]
    pub foxglove: Option<SocketAddr>,
    /// The control socket consoles attach to (default: $RUNTIME_DIRECTORY/adrive.sock
    /// under systemd, else $XDG_RUNTIME_DIR/adrive/adrive.sock, else
    /// /tmp/adrive-UID/adrive.sock).
    #[arg(long, value_name = "PATH")]
    pub socket: Option<PathBuf>,
}

#[derive(Args, Debug, Clone, Default)]
pub struct AttachArgs {
    /// The running adrive's control socket (default: as `adrive --socket`'s).
    #[arg(long, value_name = "PATH", conflicts_with = "vehicle")]
    pub socket: Option<PathBuf>,
    /// Attach to the vehicle ID of the fleet instead, over Zenoh (built with the cargo
    /// feature `fleet`): watching, and commanding with its key.
    #[arg(long, value_name = "ID")]
    pub vehicle: Option<String>,
    /// With --vehicle: the fleet's Zenoh router to connect to (repeatable, or
    /// comma-separated).
    #[arg(long, value_name = "ENDPOINT", value_delimiter = ',', default_value = config::fleet::DEFAULT_CONNECT)]
    pub connect: Vec<String>,
    /// With --vehicle: the vehicle's key file (its `[network] key_file`), which lets
    /// this console command it; without it, it watches.
    #[arg(long, value_name = "FILE", requires = "vehicle")]
    pub key: Option<PathBuf>,
    /// Keymap TOML merged over the built-in one (default: ~/.config/adrive/keymap.toml if present).
    #[arg(long, value_name = "FILE")]
    pub keymap: Option<PathBuf>,
    /// Teleop deadman of this console (100ms to 5s) [default: 1s].
    #[arg(long, value_name = "DURATION", value_parser = config::limits::parse_deadman)]
    pub deadman: Option<Duration>,
}

#[derive(Args, Debug, Clone)]
pub struct CharacterizeArgs {
    /// The device to measure: a setpoint actuator (reporting its `position`), a state
    /// actuator (every transition timed) or a sensor (its update rate and noise,
    /// listening only).
    #[arg(value_name = "DEVICE")]
    pub device: String,
    #[command(flatten)]
    pub vehicle: VehicleArgs,
    /// Where to write summary.json, samples.csv, sim.toml and report.md [default:
    /// characterize-DEVICE].
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,
    /// The procedures to run (repeatable, or comma-separated) [default: all].
    #[arg(long, value_name = "NAME", value_delimiter = ',', value_enum)]
    pub procedure: Vec<crate::characterize::Procedure>,
    /// The part of the device's range to characterize, inside it: `--range -0.5,0.5`
    /// [default: all of it].
    #[arg(long, value_name = "LO,HI", allow_hyphen_values = true, value_parser = parse_range)]
    pub range: Option<[f64; 2]>,
    /// The sweep's point spacing and the deadband search's floor, in the device's units
    /// (a thousandth to a fifth of the range) [default: five sweep points, the deadband
    /// to 1/17000 of the range].
    #[arg(long, value_name = "R")]
    pub resolution: Option<f64>,
    /// Do not ask for confirmation (for scripts): the operator has made sure the
    /// device may move.
    #[arg(long)]
    pub yes: bool,
    /// The control socket (`adrive ctl stop` reaches the run there; default: as
    /// `adrive --socket`'s).
    #[arg(long, value_name = "PATH")]
    pub socket: Option<PathBuf>,
    /// Directory of the rolling log file (default: as `adrive --log-dir`'s).
    #[arg(long, value_name = "DIR")]
    pub log_dir: Option<PathBuf>,
    /// Record the run into an MCAP file, or rolling files in a directory, as `adrive
    /// --record` does (`adrive replay` shows it); default: the vehicle file's `[record]`.
    #[arg(long, value_name = "FILE.mcap")]
    pub record: Option<PathBuf>,
    /// Record the raw serial traffic of every device too.
    #[arg(long)]
    pub record_raw: bool,
}

#[derive(Args, Debug, Clone)]
pub struct CtlArgs {
    /// What to do.
    #[command(subcommand)]
    pub what: CtlCmd,
    /// The running adrive's control socket (default: as `adrive --socket`'s).
    #[arg(long, value_name = "PATH", global = true, conflicts_with = "vehicle")]
    pub socket: Option<PathBuf>,
    /// Ask the vehicle ID of the fleet instead, over Zenoh (built with the cargo
    /// feature `fleet`).
    #[arg(long, value_name = "ID", global = true)]
    pub vehicle: Option<String>,
    /// With --vehicle: the fleet's Zenoh router to connect to (repeatable, or
    /// comma-separated).
    #[arg(long, value_name = "ENDPOINT", global = true, value_delimiter = ',', default_value = config::fleet::DEFAULT_CONNECT)]
    pub connect: Vec<String>,
    /// With --vehicle: the vehicle's key file (its `[network] key_file`), needed for
    /// everything but the status.
    #[arg(long, value_name = "FILE", global = true)]
    pub key: Option<PathBuf>,
}

#[derive(Subcommand, Debug, Clone)]
pub enum CtlCmd {
    /// The vehicle now: the gate, who commands, every device (a table, or --json: the
    /// snapshot).
    Status {
        #[arg(long)]
        json: bool,
    },
    /// Engage, as an operator: the vehicle is held in the safe state, commanded by you,
    /// until you release it (to a planner), stop or disengage it, or a console takes it.
    Engage,
    /// Stop: disengage, throttle 0, brake full. Never refused.
    Stop,
    /// Disengage into the stop state. Never refused.
    Disengage,
    /// Give command up: a planner picks the vehicle up by engaging within the watchdog
    /// timeout, or it is stopped.
    Release,
}

#[derive(Subcommand, Debug, Clone)]
pub enum RecordCmd {
    /// Channels, duration, message counts, commands refused, faults; whether the file
    /// was finished or cut off.
    Info {
        /// The recording (.mcap).
        file: PathBuf,
    },
    /// Write a finished copy (summary and index) of a recording that was not finished
    /// (killed, a power loss, cut inside a chunk): every message that can be read.
    /// Next to it as NAME.repaired.mcap, or to --out; never over an existing file.
    Repair {
        /// The recording (.mcap).
        file: PathBuf,
        /// Where to write the copy [default: NAME.repaired.mcap beside FILE].
        #[arg(long, value_name = "FILE")]
        out: Option<PathBuf>,
    },
}

#[derive(Args, Debug, Clone)]
pub struct ReplayArgs {
    /// The recording (.mcap).
    pub file: PathBuf,
    /// Also send each snapshot played as the state broadcast, to ADDR (repeatable;
    /// default 127.0.0.1:47577), so other tools can be tested against a past drive.
    #[arg(long, value_name = "ADDR", num_args = 0..=1, default_missing_value = config::network::DEFAULT_BROADCAST, value_parser = config::network::parse_destination)]
    pub broadcast: Vec<SocketAddr>,
    /// No console: play through once (with --broadcast), then exit.
    #[arg(long, requires = "broadcast")]
    pub headless: bool,
    /// Play this many times faster (0.125 to 32) [default: 1].
    #[arg(long, value_name = "X")]
    pub speed: Option<f64>,
    /// Keymap TOML merged over the built-in one, as for `adrive run`.
    #[arg(long, value_name = "FILE")]
    pub keymap: Option<PathBuf>,
    /// Play nothing: decide every command the recording received again under this
    /// vehicle file's rules and limits, and list each decision that would differ
    /// (exit status 1 when any does, 0 when none).
    #[arg(long, value_name = "VEHICLE.toml", conflicts_with_all = ["broadcast", "headless", "speed", "keymap"])]
    pub check: Option<PathBuf>,
}

#[derive(Args, Debug, Clone)]
pub struct ExportArgs {
    /// The recording (.mcap).
    pub file: PathBuf,
    /// Write one CSV file per channel into this directory (created if needed).
    #[arg(long, value_name = "DIR", required = true)]
    pub csv: PathBuf,
}

#[derive(Args, Debug, Clone)]
pub struct SendArgs {
    /// Commands, e.g. `steer 0.2`, `engage trans drive accel 0.3`: each verb starts a line.
    #[arg(required = true, value_name = "COMMAND", allow_hyphen_values = true)]
    pub words: Vec<String>,
    /// The adrive to send to: its `--listen` address (IP:PORT or HOST:PORT).
    #[arg(long, value_name = "ADDR", default_value = config::network::DEFAULT_LISTEN, value_parser = config::network::parse_peer)]
    pub to: SocketAddr,
    /// Repeat the datagram this many times a second, with a rolling `seq`, until
    /// interrupted (as a planner would).
    #[arg(long, value_name = "HZ")]
    pub rate: Option<f64>,
    /// Stop after this many datagrams (with --rate).
    #[arg(long, value_name = "N")]
    pub count: Option<u64>,
    /// Sign every datagram with this shared key file (HMAC-SHA256, seq = Unix ns).
    #[arg(long, value_name = "FILE")]
    pub key: Option<PathBuf>,
}

#[derive(Args, Debug, Clone)]
pub struct WatchArgs {
    /// Print each broadcast as it came: one JSON object per line.
    #[arg(long)]
    pub json: bool,
    /// The address the broadcast is sent to (the vehicle file's `[network]`
    /// broadcast_to): this host's, or a multicast group.
    #[arg(long, value_name = "ADDR", default_value = config::network::DEFAULT_BROADCAST, value_parser = config::network::parse_destination)]
    pub from: SocketAddr,
    /// Stop after this many broadcasts (with --ros2: report lines).
    #[arg(long, value_name = "N")]
    pub count: Option<u64>,
    /// Watch the ROS 2 graph over Zenoh instead: list every vehicle seen, follow one
    /// (built with the cargo feature `ros2`).
    #[arg(long)]
    pub ros2: bool,
    /// With --ros2: a Zenoh router or peer to connect to (repeatable).
    #[arg(long, value_name = "ENDPOINT", default_value = config::ros2::DEFAULT_CONNECT)]
    pub connect: Vec<String>,
    /// With --ros2: the ROS domain (ROS_DOMAIN_ID).
    #[arg(long, value_name = "ID", default_value_t = 0)]
    pub domain: u32,
    /// With --ros2: the vehicle to follow, by namespace (default: the first one seen).
    #[arg(long, value_name = "NS")]
    pub namespace: Option<String>,
}

#[derive(Args, Debug, Clone)]
pub struct FleetArgs {
    /// Print JSON: an array of vehicles (with --watch: one object per line).
    #[arg(long)]
    pub json: bool,
    /// Print a line each time a vehicle comes, changes (engaged, why, who commands,
    /// faults) or goes, until interrupted.
    #[arg(long)]
    pub watch: bool,
    /// The fleet's Zenoh router (or a peer) to connect to (repeatable, or
    /// comma-separated).
    #[arg(long, value_name = "ENDPOINT", value_delimiter = ',', default_value = config::fleet::DEFAULT_CONNECT)]
    pub connect: Vec<String>,
    /// How long to listen for vehicles before the list (without --watch).
    #[arg(long, value_name = "DURATION", default_value = "1s", value_parser = config::parse_duration)]
    pub wait: Duration,
    /// The list in the console, live, to pick a vehicle from and attach to it (Enter);
    /// quitting that console comes back to the list.
    #[arg(long, conflicts_with_all = ["json", "watch"])]
    pub pick: bool,
    /// With --pick: the key file the consoles attach with (a vehicle's `[network]
    /// key_file`), to command a vehicle that allows it; without it, they watch.
    #[arg(long, value_name = "FILE", requires = "pick")]
    pub key: Option<PathBuf>,
    /// With --pick: keymap TOML merged over the built-in one.
    #[arg(long, value_name = "FILE", requires = "pick")]
    pub keymap: Option<PathBuf>,
    /// With --pick: the consoles' teleop deadman (100ms to 5s) [default: 1s].
    #[arg(long, value_name = "DURATION", value_parser = config::limits::parse_deadman, requires = "pick")]
    pub deadman: Option<Duration>,
    /// Be the fleet's Zenoh router (for a fleet that has none), until interrupted.
    #[arg(long, conflicts_with_all = ["json", "watch", "pick"])]
    pub router: bool,
    /// With --router: the endpoints it listens on (repeatable, or comma-separated)
    /// [default: tcp/0.0.0.0:7447].
    #[arg(
        long,
        value_name = "ENDPOINT",
        value_delimiter = ',',
        requires = "router"
    )]
    pub listen: Vec<String>,
}

#[derive(Args, Debug, Clone)]
pub struct SimArgs {
    /// Vehicle TOML whose devices to simulate (default: the built-in Alice).
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,
    /// Simulate just these devices (repeatable, or comma-separated).
    #[arg(long, value_name = "NAME", value_delimiter = ',')]
    pub only: Vec<String>,
    /// Do not print what each device receives.
    #[arg(long, short)]
    pub quiet: bool,
    /// Inject a fault or event at start, as typed on standard input (repeatable):
    /// `--fault "silent gas on" --fault "slow steer 80"`.
    #[arg(long, value_name = "LINE")]
    pub fault: Vec<String>,
}

/// Entry point; returns the process status.
pub fn main() -> i32 {
    let cli = Cli::parse();
    let result = match cli.command {
        Some(Cmd::Run(args)) => run(args),
        Some(Cmd::Sim(args)) => sim(args),
        Some(Cmd::Ports) => {
            let ports = crate::port_list::scan(Path::new("/sys"), Path::new("/dev"));
            let ptys = crate::port_list::pseudo_terminals(Path::new("/dev"));
            let sims = crate::port_list::simulated(&std::env::temp_dir(), Path::new("/proc"));
            print_out(crate::port_list::report(&ports, &ptys, &sims).as_bytes())
        }
        Some(Cmd::Send(args)) => send(args),
        Some(Cmd::Watch(args)) => watch(args),
        Some(Cmd::Fleet(args)) => fleet::list(&args),
        Some(Cmd::Attach(args)) => attach(args),
        Some(Cmd::Ctl(args)) => ctl(args),
        Some(Cmd::Characterize(args)) => characterize(args),
        Some(Cmd::Replay(args)) => replay(args),
        Some(Cmd::Record {
            command: RecordCmd::Info { file },
        }) => record_info(&file),
        Some(Cmd::Record {
            command: RecordCmd::Repair { file, out },
        }) => record_repair(&file, out.as_deref()),
        Some(Cmd::Export(args)) => export(args),
        Some(Cmd::Completions { shell }) => {
            // Into memory first: clap_complete panics when its writer fails.
            let mut script = Vec::new();
            clap_complete::generate(shell, &mut Cli::command(), "adrive", &mut script);
            print_out(&script)
        }
        Some(Cmd::Manpage { dir }) => manpage(dir.as_deref(), &mut std::io::stdout()).map(|()| 0),
        None => run(cli.run),
    };
    match result {
        Ok(code) => code,
        Err(e) if closed_output(&e) => 0,
        Err(e) => {
            tell(io::stderr(), format_args!("adrive: {e:#}\n"));
            2
        }
    }
}

fn load(path: &Option<PathBuf>, only: &[String]) -> anyhow::Result<VehicleConfig> {
    let mut c = match path {
        Some(p) => config::load(p)?,
        None => VehicleConfig::alice(),
    };
    let source = c.source.clone();
    c.retain_only(only)
        .map_err(|e| anyhow::anyhow!("{e} in {source}"))?;
    Ok(c)
}

fn default_log_dir() -> PathBuf {
    std::env::var_os("XDG_STATE_HOME")
        .map(PathBuf::from)
        .or_else(|| std::env::var_os("HOME").map(|h| PathBuf::from(h).join(".local/state")))
        .map(|d| d.join("adrive"))
        .unwrap_or_else(|| PathBuf::from("logs"))
}

/// `adrive run`: the engine with the console or headless.
pub fn run(args: RunArgs) -> anyhow::Result<i32> {
    let mut config = args.vehicle.load()?;
    if let Some(d) = args.terminal_timeout {
        config.console.terminal_timeout = d;
    }
    if let Some(addr) = args.listen {
        config.network.listen = addr;
    }
    if let Some(d) = args.give_up_after {
        config.supervisor.give_up_after = Some(d);
    }
    if !args.broadcast_to.is_empty() {
        config.network.broadcast_to = args.broadcast_to.clone();
    }
    let auth = network_key(&config)?;
    let joining = config::FleetConfig::joining(
        config.fleet.as_ref(),
        args.fleet.as_deref(),
        &args.fleet_connect,
    )
    .map_err(anyhow::Error::msg)?;
    if joining.as_ref().is_some_and(|f| f.command) && auth.is_none() {
        let v = config::Violation {
            paths: vec!["command".into()],
            message: "command: a vehicle commanded from the fleet needs its key, which a link \
                      proves: set [network] key_file"
                .into(),
        };
        return Err(config.refuse("fleet", v).into());
    }
    let log_dir = args.log_dir.clone().unwrap_or_else(default_log_dir);
    // So does `--ros2` on a build without it.
    ros2::built(args.ros2)?;
    // A bad keymap, or no terminal for the console, stops here, before anything starts.
    let keymap = if args.headless {
        None
    } else {
        let keymap = console::keymap::Keymap::for_run(args.keymap.as_deref())?;
        console::terminal::check_standard_streams(console::terminal::RUN_WITHOUT)
            .map_err(anyhow::Error::msg)?;
        Some(keymap)
    };
    // A port another adrive (or program) holds stops here too: each port is opened
    // and locked now, and handed to its device as its first open.
    let opened = args.vehicle.open_ports(&config)?;
    // Every path given is what it must be before anything starts: the log's directory,
    // the recording's file (or directory of rolling files), the control socket's place.
    paths::create_dir("--log-dir", &log_dir).map_err(anyhow::Error::msg)?;
    let recording = record::Options::of(args.record.as_deref(), args.record_raw, &config);
    if let Some(r) = &recording {
        check_recording(args.record.is_some(), r)?;
    }
    let socket_path = args
        .socket
        .clone()
        .unwrap_or_else(socket::path::default_path);
    paths::check_place("--socket", &socket_path).map_err(anyhow::Error::msg)?;
    let tap = Arc::new(crate::vehicle::tap::Tap::default());
    // The log pane's lines, for the embedded console and every attached one.
    let ring = crate::logging::ring::LogRing::default();
    let mut extra: Vec<logging::ExtraLayer> = vec![Box::new(ring.layer())];
    if recording.is_some() || args.foxglove.is_some() {
        extra.push(Box::new(record::log::TapLayer { tap: tap.clone() }));
    }
    let log = logging::init_with(args.headless, Some(&log_dir), extra)?;
    for w in keymap.iter().flat_map(|k| k.warnings()) {
        tracing::warn!("keymap: {w}");
    }
    // A live control socket (another adrive) stops here, before anything is driven or
    // simulated, named; a stale one is replaced.
    let claimed = socket::path::bind(&socket_path).map_err(anyhow::Error::msg)?;
    // So does a fleet id another vehicle on the network has.
    let mut member = fleet::join(joining.as_ref(), &config.vehicle.name)?;
    let (sim, vehicle, recorder) = bring_up(args.vehicle.sim, config, opened, tap, recording)?;
    let live = match args.foxglove {
        Some(addr) => Some(crate::foxglove::Foxglove::start(&vehicle, addr)?),
        None => None,
    };
    let gate = Arc::new(Gate::new(vehicle.clone()));
    gate.announce();
    let exits = exit::install()?;
    // The command socket is bound before any device is driven: a busy port is a
    // configuration error (status 2), not a half-started vehicle.
    let fleet_key = auth.clone();
    let net = Net::start(gate.clone(), vehicle.config().network.clone(), auth)?;
    let ros2 = ros2::start(args.ros2, &gate, &net, vehicle.config())?;
    member.publish(&gate)?;
    let sources = crate::controls::Sources {
        logs: Some(ring),
        net: Some(net.status().clone()),
        sim: sim.clone(),
    };
    let control = socket::Server::start(gate.clone(), sources.clone(), claimed)
        .map_err(anyhow::Error::msg)?;
    member.serve(&control, fleet_key)?;
    let (panic_in, panic_after) = match args.inject_panic.as_deref() {
        None => ("", Duration::ZERO),
        Some(spec) => match spec.split_once(':') {
            Some((t, d)) => (t, config::parse_duration(d).map_err(anyhow::Error::msg)?),
            None => (spec, Duration::from_millis(1500)),
        },
    };
    if let Some(hang) = args.inject_hang.as_deref() {
        crate::threads::inject_hang(parse_hang(hang).map_err(anyhow::Error::msg)?);
    }
    let engine = Engine::start_injected(gate.clone(), injected(panic_in, panic_after))?;
    let monitor = crate::engine::monitor::Monitor::start(gate.clone())?;
    let mut sup_cfg = vehicle.config().supervisor.clone();
    sup_cfg.panic_for_test = (panic_in == "supervisor").then_some(panic_after);
    let supervisor = crate::supervisor::start_watching(
        gate.clone(),
        sup_cfg,
        Box::new(exit::request),
        engine.liveness().with(&monitor.liveness()),
    )?;
    // Let the devices report first, so the unwinding really has a vehicle to stop; with
    // the console, it panics from its own loop, so the terminal is taken over then.
    let panic_main = panic_in == "main";
    if panic_main && keymap.is_none() {
        let _ = exits.recv_timeout(panic_after);
        panic!("injected panic (--inject-panic main)");
    }
    tracing::info!(threads = ?engine.thread_names(), sim = args.vehicle.sim, "engine started");
    service_ready(&engine);
    let why = match keymap {
        None => headless::wait(&gate, &exits),
        Some(keymap) => {
            let opts = console::Options {
                keymap,
                deadman: args.deadman.unwrap_or(config::limits::DEADMAN_DEFAULT),
                sources,
                panic_after: panic_main.then_some(panic_after),
            };
            match console::run_with(&gate, &exits, opts) {
                Ok(why) => why,
                // Still stop safely below.
                Err(e) => {
                    tell(io::stderr(), format_args!("adrive: console: {e}\n"));
                    Exit::Panic(format!("console: {e}"))
                }
            }
        }
    };
    crate::service::stopping(&why.describe());
    tracing::info!("stopping: {}", why.describe());
    // No network command may follow the safe state: refuse datagrams, disengage (which
    // commands the safe state at once), stop the network and gate threads, then let the
    // engine command the safe state again and wait for its acknowledgement.
    net.close();
    ros2.close();
    control.close();
    gate.disengage(crate::snapshot::DisengageCause::Stopping {
        why: Some(why.describe()),
    });
    let net_figures = net.status().snapshot(&gate);
    let mut stuck = supervisor.shutdown(Duration::from_millis(500));
    stuck.extend(net.shutdown(Duration::from_millis(500)));
    stuck.extend(ros2.shutdown(Duration::from_millis(500)));
    stuck.extend(member.shutdown(Duration::from_millis(500)));
    stuck.extend(control.shutdown(Duration::from_millis(500)));
    stuck.extend(monitor.shutdown(Duration::from_millis(200)));
    let (safe, engine_stuck) = engine.shutdown(Duration::from_secs(2));
    stuck.extend(engine_stuck);
    // After the engine: the safe state's commands are in the recording.
    stuck.extend(recorder.shutdown(Duration::from_secs(2)));
    stuck.extend(live.shutdown(Duration::from_millis(500)));
    if safe {
        tracing::info!(
            "safe state acknowledged: {}",
            headless::safe_state_words(&vehicle)
        );
    }
    drop(sim);
    if args.headless {
        for d in vehicle.devices() {
            d.stats().refresh();
        }
        tell(
            io::stdout(),
            format_args!(
                "{}{}\n",
                headless::summary(&gate.snapshot(0)),
                headless::net_summary(&net_figures, &gate.view(Instant::now()))
            ),
        );
        if let Some(r) = vehicle.tap().status() {
            tell(
                io::stdout(),
                format_args!("{}\n", headless::record_summary(&r)),
            );
        }
    }
    // The console's screen is gone: the terminal says how adrive ended, as a headless
    // run's summary does (a terminal that went away drops it).
    if !args.headless && safe && stuck.is_empty() {
        say_at_end(format!(
            "adrive: stopped ({}); safe state acknowledged: {}; log in {}\n",
            why.describe(),
            headless::safe_state_words(&vehicle),
            log_dir.display()
        ));
    }
    if !safe || !stuck.is_empty() {
        let msg = format!(
            "stopped ({}) but the safe state was {}acknowledged{}",
            why.describe(),
            if safe { "" } else { "NOT " },
            if stuck.is_empty() {
                String::new()
            } else {
                format!("; threads still running: {}", stuck.join(", "))
            }
        );
        tracing::error!("{msg}");
        say_at_end(format!("adrive: {msg}\n"));
    }
    let code = exit::status(&why, safe, stuck.is_empty());
    drop(log);
    Ok(code)
}

/// A recording's file (or directory of rolling files) is what it must be before
/// anything starts; `given`: named by `--record`, else by the vehicle file's `[record]`.
fn check_recording(given: bool, r: &record::Options) -> anyhow::Result<()> {
    let what = if given { "--record" } else { "[record] dir" };
    match &r.target {
        record::Target::File(p) => paths::check_new_file(what, p),
        record::Target::Dir { dir, .. } => paths::check_dir_possible(what, dir),
    }
    .map_err(anyhow::Error::msg)
}

/// `--range LO,HI`: two numbers.
fn parse_range(text: &str) -> Result<[f64; 2], String> {
    let parts: Vec<&str> = text.split(',').map(str::trim).collect();
    match parts[..] {
        [lo, hi] => match (lo.parse::<f64>(), hi.parse::<f64>()) {
            (Ok(lo), Ok(hi)) => Ok([lo, hi]),
            _ => Err(format!(
                "expected LO,HI, two numbers (-0.5,0.5), got {text:?}"
            )),
        },
        _ => Err(format!(
            "expected LO,HI, two numbers (-0.5,0.5), got {text:?}"
        )),
    }
}

/// `adrive characterize DEVICE`: the engine without a console or network, the
/// procedures of [`crate::characterize`] as the one commander, then the safe state.
pub fn characterize(args: CharacterizeArgs) -> anyhow::Result<i32> {
    let mut config = args.vehicle.load()?;
    let Some(d) = config.devices.iter_mut().find(|d| d.name == args.device) else {
        anyhow::bail!("no device {:?} in {}", args.device, config.source);
    };
    // Sample the device fast: the figures are read between its polls.
    d.status_period = d.status_period.min(crate::characterize::background::POLL);
    let kind = d.kind;
    let scope = crate::characterize::Scope {
        range: args.range,
        resolution: args.resolution,
    };
    let setpoint_only = [
        (!args.procedure.is_empty(), "--procedure"),
        (args.range.is_some(), "--range"),
        (args.resolution.is_some(), "--resolution"),
    ]
    .into_iter()
    .find_map(|(given, name)| given.then_some(name));
    if kind == crate::value::Kind::Setpoint {
        scope
            .check(d.range())
            .map_err(|e| anyhow::anyhow!("{}: {e}", args.device))?;
    } else if let Some(option) = setpoint_only {
        anyhow::bail!(
            "{option} applies to a setpoint actuator; {} is a {kind} device: {}",
            args.device,
            if kind == crate::value::Kind::State {
                "every transition between its states is timed"
            } else {
                "it is listened to (update rate and noise)"
            }
        );
    }
    let out = args
        .out
        .clone()
        .unwrap_or_else(|| PathBuf::from(format!("characterize-{}", args.device)));
    let procedures = if args.procedure.is_empty() {
        crate::characterize::Procedure::ALL.to_vec()
    } else {
        args.procedure.clone()
    };
    // A sensor is only listened to: nothing moves, nothing to confirm.
    if !args.yes && kind != crate::value::Kind::Sensor {
        use std::io::IsTerminal;
        if !io::stdin().is_terminal() {
            anyhow::bail!(
                "characterize moves {} on its own: confirm on a terminal, or with --yes",
                args.device
            );
        }
        tell(
            io::stdout(),
            format_args!(
                "{} Is it free to move, the vehicle stopped, {}the brake held? [y/N] ",
                if kind == crate::value::Kind::State {
                    format!(
                        "characterize shifts {} through all its states on its own.",
                        args.device
                    )
                } else {
                    format!(
                        "characterize moves {} across its range on its own.",
                        args.device
                    )
                },
                if kind == crate::value::Kind::State {
                    ""
                } else {
                    "in park, "
                },
            ),
        );
        let mut answer = String::new();
        io::stdin().read_line(&mut answer)?;
        if !matches!(answer.trim(), "y" | "Y" | "yes") {
            tell(io::stdout(), format_args!("not confirmed: nothing moved\n"));
            return Ok(1);
        }
    }
    let log_dir = args.log_dir.clone().unwrap_or_else(default_log_dir);
    paths::create_dir("--log-dir", &log_dir).map_err(anyhow::Error::msg)?;
    let socket_path = args
        .socket
        .clone()
        .unwrap_or_else(socket::path::default_path);
    paths::check_place("--socket", &socket_path).map_err(anyhow::Error::msg)?;
    let recording = record::Options::of(args.record.as_deref(), args.record_raw, &config);
    if let Some(r) = &recording {
        check_recording(args.record.is_some(), r)?;
    }
    let opened = args.vehicle.open_ports(&config)?;
    let tap = Arc::new(crate::vehicle::tap::Tap::default());
    let mut extra: Vec<logging::ExtraLayer> = Vec::new();
    if recording.is_some() {
        extra.push(Box::new(record::log::TapLayer { tap: tap.clone() }));
    }
    let log = logging::init_with(true, Some(&log_dir), extra)?;
    let claimed = socket::path::bind(&socket_path).map_err(anyhow::Error::msg)?;
    let (sim, vehicle, recorder) = bring_up(args.vehicle.sim, config, opened, tap, recording)?;
    let gate = Arc::new(Gate::new(vehicle.clone()));
    gate.announce();
    let exits = exit::install()?;
    let sources = crate::controls::Sources {
        logs: None,
        net: None,
        sim: sim.clone(),
    };
    let control =
        socket::Server::start(gate.clone(), sources, claimed).map_err(anyhow::Error::msg)?;
    let engine = Engine::start(gate.clone())?;
    let monitor = crate::engine::monitor::Monitor::start(gate.clone())?;
    let supervisor = crate::supervisor::start_watching(
        gate.clone(),
        vehicle.config().supervisor.clone(),
        Box::new(exit::request),
        engine.liveness().with(&monitor.liveness()),
    )?;
    // Standard output may be closed (`| head`): what it says must never end the run.
    tell(
        io::stdout(),
        format_args!(
            "characterizing {} ({}): STOP with `adrive ctl stop`, or Ctrl-C\n",
            args.device,
            match kind {
                crate::value::Kind::Setpoint => procedures
                    .iter()
                    .map(|p| format!("{p:?}").to_lowercase())
                    .collect::<Vec<_>>()
                    .join(", "),
                crate::value::Kind::State => "every transition between its states".into(),
                crate::value::Kind::Sensor => {
                    "listening only: update rate and noise; nothing is commanded".into()
                }
            }
        ),
    );
    let stop = || exits.try_recv().ok().map(|why| why.describe());
    let watch = crate::characterize::Watch {
        progress: &|_| {},
        stop: &stop,
    };
    let result = crate::characterize::run_any(&gate, &watch, &args.device, &procedures, &scope);
    control.close();
    gate.disengage(crate::snapshot::DisengageCause::Stopping { why: None });
    let mut stuck = supervisor.shutdown(Duration::from_millis(500));
    stuck.extend(control.shutdown(Duration::from_millis(500)));
    stuck.extend(monitor.shutdown(Duration::from_millis(200)));
    let (safe, engine_stuck) = engine.shutdown(Duration::from_secs(2));
    stuck.extend(engine_stuck);
    // After the engine: the safe state's commands are in the recording.
    stuck.extend(recorder.shutdown(Duration::from_secs(2)));
    // Where the device ended: a setpoint actuator's position, a state actuator's state.
    let at = vehicle.find(&args.device).and_then(|d| {
        let c = d.config();
        match (c.position(), c.state()) {
            (Some(i), _) => d
                .reading(i)
                .map(|p| crate::value::Value::Number(p).to_string()),
            (None, Some(i)) => d.reading(i).map(|s| {
                c.states
                    .get(s as usize)
                    .cloned()
                    .unwrap_or_else(|| s.to_string())
            }),
            _ => None,
        }
    });
    drop(sim);
    let code = match result {
        Ok(figures) => {
            figures
                .write_all(&out)
                .map_err(|e| anyhow::anyhow!("--out {}: {e}", out.display()))?;
            let mut summary = figures.summary();
            if let Some(o) = summary.as_object_mut() {
                o.remove("map");
            }
            tell(
                io::stdout(),
                format_args!(
                    "{}\nwritten to {} in {:.1} s\n",
                    serde_json::to_string_pretty(&summary)?,
                    out.display(),
                    figures.took()
                ),
            );
            0
        }
        Err(e) => {
            tell(
                io::stderr(),
                format_args!("adrive: characterize {}: {e}\n", args.device),
            );
            1
        }
    };
    // A sensor is only listened to: nothing of it to say where it ended.
    let ended = match (kind, at) {
        (crate::value::Kind::Sensor, _) => format!("{} listened to", args.device),
        (_, at) => format!("{} at {}", args.device, at.unwrap_or_else(|| "?".into())),
    };
    tell(
        io::stdout(),
        format_args!(
            "{ended}; safe state {}acknowledged\n",
            if safe { "" } else { "NOT " }
        ),
    );
    if let Some(r) = vehicle.tap().status() {
        tell(
            io::stdout(),
            format_args!("{}\n", headless::record_summary(&r)),
        );
    }
    drop(log);
    Ok(if !safe || !stuck.is_empty() {
        exit::UNSAFE
    } else {
        code
    })
}

/// Tell systemd (if it runs adrive) that adrive is ready, once every device thread
/// runs.
fn service_ready(engine: &Engine) {
    let alive = engine.liveness();
    let late = alive.wait_running(Instant::now() + Duration::from_secs(2));
    if late.is_empty() {
        let n = engine.vehicle().devices().len();
        crate::service::ready(&format!("running: {n} devices"));
    } else {
        // Not ready: systemd's start timeout (or the watchdog) will tell.
        tracing::error!(threads = ?late, "device threads not running 2 s after the start");
    }
}

/// `--inject-hang THREAD:AFTER:FOR`.
fn parse_hang(text: &str) -> Result<crate::threads::HangSpec, String> {
    let mut parts = text.rsplitn(3, ':');
    let (Some(hang), Some(after), Some(thread)) = (parts.next(), parts.next(), parts.next()) else {
        return Err(format!(
            "expected THREAD:AFTER:FOR (steer/status:2s:5s), got {text:?}"
        ));
    };
    Ok(crate::threads::HangSpec {
        thread: thread.to_string(),
        after: config::parse_duration(after)?,
        hang: config::parse_duration(hang)?,
    })
}

/// `--inject-panic DEVICE/status` (a panic) or `DEVICE/status=return` (the thread
/// ends quietly): a fault for the engine to inject, for tests.
fn injected(thread: &str, after: Duration) -> Option<crate::engine::Injected> {
    let (thread, panic) = match thread.split_once('=') {
        Some((t, "return")) => (t, false),
        _ => (thread, true),
    };
    thread
        .ends_with("/status")
        .then(|| crate::engine::Injected {
            thread: thread.to_string(),
            after,
            panic,
        })
}

/// The vehicle both the run and `characterize` drive: its simulator (`sim`), its
/// devices (each port opened beforehand, in `opened`, handed over as its first open)
/// and its recorder — a recording that cannot start is refused before anything is
/// driven.
type BroughtUp = (Option<Arc<Sim>>, Arc<Vehicle>, Option<Recorder>);
fn bring_up(
    sim: bool,
    mut config: VehicleConfig,
    mut opened: std::collections::HashMap<String, Box<dyn driver::Link>>,
    tap: Arc<crate::vehicle::tap::Tap>,
    recording: Option<record::Options>,
) -> anyhow::Result<BroughtUp> {
    let sim = if sim {
        let s = Sim::start(&config, None)?;
        s.patch(&mut config);
        Some(Arc::new(s))
    } else {
        None
    };
    let vehicle = Arc::new(Vehicle::with_tap(
        config,
        |c| {
            let (path, baud, timeout) = (c.port.clone(), c.baud, c.reply_timeout);
            let mut first = opened.remove(c.name.as_str());
            Box::new(move || match first.take() {
                Some(link) => Ok(link),
                None => driver::open_serial(&path, baud, timeout),
            })
        },
        tap,
    ));
    let recorder = match recording {
        Some(opts) => {
            Some(Recorder::start(&vehicle, opts).map_err(|e| anyhow::anyhow!("record: {e}"))?)
        }
        None => None,
    };
    Ok((sim, vehicle, recorder))
}

/// Open and lock every device's port, before anything starts: a port in use by another
/// process (a second adrive on the same vehicle) is refused, named with its holder.
/// A port that cannot be opened for another reason (unplugged, a wrong path) is left
/// to the engine, which reports it `disconnected` and reconnects when it appears.
fn open_ports(
    config: &VehicleConfig,
) -> anyhow::Result<std::collections::HashMap<String, Box<dyn driver::Link>>> {
    let mut opened = std::collections::HashMap::new();
    // A device on a CAN bus has no port of its own: its bus's reader opens the adapter.
    for d in config
        .devices
        .iter()
        .filter(|d| d.driver != crate::config::device::DriverKind::Can)
    {
        match driver::open_serial(&d.port, d.baud, d.reply_timeout) {
            Ok(link) => {
                opened.insert(d.name.clone(), link);
            }
            Err(e) if e.kind() == io::ErrorKind::ResourceBusy => {
                anyhow::bail!(
                    "device {}: {e}; is another adrive running on this vehicle? \
                     (`adrive watch` shows a running one)",
                    d.name
                )
            }
            Err(_) => {}
        }
    }
    Ok(opened)
}

/// `bytes` to standard output, whole; a failure (its reader gone) is the caller's.
fn print_out(bytes: &[u8]) -> anyhow::Result<i32> {
    let mut out = io::stdout().lock();
    out.write_all(bytes)?;
    out.flush()?;
    Ok(0)
}

/// The error is standard output closed by its reader (`adrive manpage | head`,
/// `adrive watch | head -2`): the output wanted has been read, and the command ends
/// quietly with status 0, as Unix tools do. Nothing else here writes to a pipe or a
/// socket that reports EPIPE: UDP does not, a serial port or terminal says EIO.
fn closed_output(e: &anyhow::Error) -> bool {
    e.chain().any(|c| {
        c.downcast_ref::<io::Error>()
            .is_some_and(|e| e.kind() == io::ErrorKind::BrokenPipe)
    })
}

/// Write to standard output or error, which may be a terminal that hung up (an SSH
/// session dropping): there a failed write is dropped, where `print!` and `eprintln!`
/// would panic on the way out.
fn tell(mut to: impl Write, text: std::fmt::Arguments) {
    let _ = to.write_fmt(text).and_then(|()| to.flush());
}

/// Say `text` on standard error at adrive's end, waiting at most a second for it to
/// be taken: the console's terminal may have stopped reading (a frozen SSH session, its
/// pseudo-terminal full), and adrive's exit — the safe state already commanded — must
/// not wait on it. Written past the standard library's lock on standard error, so that
/// a write left blocked holds up no other.
fn say_at_end(text: String) {
    let (done, wait) = crossbeam_channel::bounded::<()>(1);
    let spawned = std::thread::Builder::new()
        .name("exit/say".into())
        .spawn(move || {
            let mut rest = text.as_bytes();
            while !rest.is_empty() {
                match rustix::io::write(rustix::stdio::stderr(), rest) {
                    Ok(0) => break,
                    Ok(n) => rest = &rest[n..],
                    Err(rustix::io::Errno::INTR) => {}
                    Err(_) => break,
                }
            }
            let _ = done.send(());
        });
    if spawned.is_ok() {
        let _ = wait.recv_timeout(Duration::from_secs(1));
    }
}

/// The `[network]` key file, relative to the vehicle file's directory.
fn network_key(config: &VehicleConfig) -> anyhow::Result<Option<Auth>> {
    let Some(file) = &config.network.key_file else {
        return Ok(None);
    };
    let path = config.relative(file);
    if let Err(why) = paths::check_file("", &path) {
        let v = config::Violation {
            paths: vec!["key_file".into()],
            message: format!("key_file: {why}"),
        };
        return Err(config.refuse("network", v).into());
    }
    let auth = Auth::load(&path).map_err(|e| {
        let v = config::Violation {
            paths: vec!["key_file".into()],
            message: format!("key_file: {e}"),
        };
        config.refuse("network", v)
    })?;
    Ok(Some(auth))
}

/// `adrive manpage`: the manual page, from the same definitions as `--help`, to `out`;
/// or, with a directory, every page (the subcommands' too) written there.
pub fn manpage(dir: Option<&Path>, out: &mut dyn std::io::Write) -> anyhow::Result<()> {
    let cmd = Cli::command().disable_help_subcommand(true);
    match dir {
        Some(dir) => {
            paths::create_dir("manpage --dir", dir).map_err(anyhow::Error::msg)?;
            clap_mangen::generate_to(cmd, dir)
                .map_err(|e| anyhow::anyhow!("manpage --dir {}: {e}", dir.display()))?;
            tell(
                io::stderr(),
                format_args!("adrive manpage: wrote the pages to {}\n", dir.display()),
            );
        }
        None => clap_mangen::Man::new(cmd).render(out)?,
    }
    Ok(())
}

/// Set when SIGINT or SIGTERM arrives (for the clients, which have no engine to stop).
fn stop_flag() -> anyhow::Result<Arc<AtomicBool>> {
    let flag = Arc::new(AtomicBool::new(false));
    for sig in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
        signal_hook::flag::register(sig, flag.clone())?;
    }
    Ok(flag)
}

/// `adrive send`: commands in one datagram, once or at a rate.
pub fn send(args: SendArgs) -> anyhow::Result<i32> {
    // The commands take every word after the first (a value may start with `-`), so
    // options written after them (`adrive send steer 0.2 --to HOST:PORT`) arrive among
    // them: take them out and read them as options.
    let send = Cli::command();
    let options: Vec<String> = send
        .find_subcommand("send")
        .expect("send is a subcommand")
        .get_arguments()
        .filter_map(|a| a.get_long())
        .map(|l| format!("--{l}"))
        .collect();
    let is_option = |w: &str| {
        options
            .iter()
            .any(|o| w.split('=').next() == Some(o.as_str()))
    };
    if args.words.iter().any(|w| is_option(w)) {
        let mut argv: Vec<String> = vec!["adrive".into(), "send".into()];
        let mut rest = Vec::new();
        let mut words = args.words.iter();
        while let Some(w) = words.next() {
            if is_option(w) {
                argv.push(w.clone());
                if !w.contains('=') {
                    argv.extend(words.next().cloned());
                }
            } else {
                rest.push(w.clone());
            }
        }
        argv.push("--".into());
        argv.extend(rest);
        return match Cli::try_parse_from(&argv) {
            Ok(Cli {
                command: Some(Cmd::Send(args)),
                ..
            }) => send_parsed(args),
            Ok(_) => unreachable!("parsed as send"),
            Err(e) => {
                let _ = e.print();
                Ok(client::status::USAGE)
            }
        };
    }
    send_parsed(args)
}

/// [`send`], its options read.
fn send_parsed(args: SendArgs) -> anyhow::Result<i32> {
    let auth = match args.key.as_deref() {
        Some(key) => {
            paths::check_file("--key", key).map_err(anyhow::Error::msg)?;
            Some(Auth::load(key).map_err(|e| anyhow::anyhow!("--key {e}"))?)
        }
        None => None,
    };
    let body = client::lines_from_words(&args.words);
    let opts = client::SendOptions {
        to: args.to,
        rate: args.rate,
        count: args.count,
        auth,
    };
    let stop = stop_flag()?;
    Ok(client::send(&opts, &body, &stop)?)
}

/// `adrive watch`: print the state broadcast, or (`--ros2`) the vehicles on a ROS 2
/// graph.
pub fn watch(args: WatchArgs) -> anyhow::Result<i32> {
    let stop = stop_flag()?;
    if args.ros2 {
        return ros2::watch(&args, &stop);
    }
    Ok(client::watch(args.from, args.json, args.count, &stop)?)
}

/// `adrive attach`: the console over a running adrive's control socket.
pub fn attach(args: AttachArgs) -> anyhow::Result<i32> {
    let keymap = console::keymap::Keymap::for_run(args.keymap.as_deref())?;
    let to: Arc<dyn socket::client::Dial> = match &args.vehicle {
        Some(id) => match fleet::dialer(&args.connect, id, args.key.as_deref()) {
            Ok(d) => d,
            Err(e) => {
                tell(io::stderr(), format_args!("adrive: {e}\n"));
                return Ok(2);
            }
        },
        None => Arc::new(args.socket.unwrap_or_else(socket::path::default_path)),
    };
    if let Err(no_terminal) =
        console::terminal::check_standard_streams(console::terminal::ATTACH_WITHOUT)
    {
        // Nothing to attach to is the first thing to know; a terminal, the next.
        if let Err(e) = socket::client::probe(&*to) {
            tell(io::stderr(), format_args!("adrive: {e}\n"));
            return Ok(1);
        }
        return Err(anyhow::Error::msg(no_terminal));
    }
    let exits = exit::install()?;
    let remote = match socket::client::Remote::attach(to.clone(), |why| {
        exit::request(Exit::Lost(why));
    }) {
        Ok(r) => r,
        Err(e) => {
            tell(io::stderr(), format_args!("adrive: {e}\n"));
            return Ok(1);
        }
    };
    let deadman = args.deadman.unwrap_or(config::limits::DEADMAN_DEFAULT);
    let why = console::drive(&remote, &exits, keymap, deadman, None)?;
    // The console gone, its connection goes: said to the far end before leaving.
    drop(remote);
    to.close();
    if let Exit::Lost(_) = why {
        tell(io::stderr(), format_args!("adrive: {}\n", why.describe()));
    }
    Ok(exit::status(&why, true, true))
}

/// `adrive ctl`: one operator command over the control socket.
pub fn ctl(args: CtlArgs) -> anyhow::Result<i32> {
    use socket::client::{once, ClientError};
    use socket::proto::{Answer, Op};
    let path = args.socket.unwrap_or_else(socket::path::default_path);
    let (op, json) = match args.what {
        CtlCmd::Status { json } => (Op::Status, json),
        CtlCmd::Engage => (Op::Engage, false),
        CtlCmd::Stop => (Op::Stop, false),
        CtlCmd::Disengage => (Op::Disengage, false),
        CtlCmd::Release => (Op::Release, false),
    };
    let what = format!("{op:?}").to_lowercase();
    if args.key.is_some() && args.vehicle.is_none() {
        anyhow::bail!(
            "--key: only with --vehicle (the control socket on this machine needs no key)"
        );
    }
    let asked = match &args.vehicle {
        Some(id) => match fleet::dialer(&args.connect, id, args.key.as_deref()) {
            Ok(to) => once(&*to, op),
            Err(e) => {
                tell(io::stderr(), format_args!("adrive: {e}\n"));
                return Ok(2);
            }
        },
        None => once(&path, op),
    };
    let answer = match asked {
        Ok(a) => a,
        Err(e) => {
            tell(io::stderr(), format_args!("adrive: {e}\n"));
            return Ok(if matches!(e, ClientError::NoReply(_)) {
                3
            } else {
                1
            });
        }
    };
    let (text, code) = match answer {
        Answer::Snapshot(snap) if json => (serde_json::to_string_pretty(&snap)?, 0),
        Answer::Snapshot(snap) => (headless::status_table(&snap), 0),
        Answer::Done(done) => (done.to_string(), 0),
        Answer::Refused(r) => {
            tell(io::stderr(), format_args!("adrive: {what} refused: {r}\n"));
            return Ok(1);
        }
        Answer::Error(e) => {
            tell(io::stderr(), format_args!("adrive: {what}: {e}\n"));
            return Ok(1);
        }
        other => (format!("{other:?}"), 0),
    };
    print_out(format!("{text}\n").as_bytes()).map(|_| code)
}

/// The ROS 2 interface when built in, and what `--ros2` says when it is not.
mod ros2 {
    use super::WatchArgs;
    use crate::config::VehicleConfig;
    use crate::engine::Gate;
    use crate::net::Net;
    use std::sync::atomic::AtomicBool;
    use std::sync::Arc;
    use std::time::Duration;

    #[cfg(not(feature = "ros2"))]
    const NOT_BUILT: &str = "--ros2: this adrive was built without ROS 2; build it with \
                             `cargo build --release --features ros2`";

    /// The running node, if `--ros2` started one.
    #[cfg(feature = "ros2")]
    pub(crate) struct Running(Option<crate::ros2::Node>);
    #[cfg(not(feature = "ros2"))]
    pub(crate) struct Running;

    #[cfg(feature = "ros2")]
    pub(crate) fn start(
        on: bool,
        gate: &Arc<Gate>,
        net: &Net,
        config: &VehicleConfig,
    ) -> anyhow::Result<Running> {
        if !on {
            return Ok(Running(None));
        }
        let node = crate::ros2::Node::start(gate.clone(), net.status().clone(), config)?;
        Ok(Running(Some(node)))
    }

    #[cfg(not(feature = "ros2"))]
    pub(crate) fn start(
        on: bool,
        _: &Arc<Gate>,
        _: &Net,
        _: &VehicleConfig,
    ) -> anyhow::Result<Running> {
        built(on)?;
        Ok(Running)
    }

    /// `--ros2` (`on`) on a build without it is refused, before anything starts.
    pub(crate) fn built(on: bool) -> anyhow::Result<()> {
        #[cfg(not(feature = "ros2"))]
        if on {
            anyhow::bail!(NOT_BUILT);
        }
        let _ = on;
        Ok(())
    }

    impl Running {
        /// Refuse every ROS 2 command from now on.
        pub(crate) fn close(&self) {
            #[cfg(feature = "ros2")]
            if let Some(n) = &self.0 {
                n.close();
            }
        }
    }

    impl crate::threads::Shutdown for Running {
        /// Stop the node; the names of the threads that did not stop.
        fn shutdown(self, deadline: Duration) -> Vec<String> {
            #[cfg(feature = "ros2")]
            if let Some(n) = self.0 {
                return n.shutdown(deadline);
            }
            let _ = deadline;
            Vec::new()
        }
    }

    #[cfg(feature = "ros2")]
    pub(crate) fn watch(args: &WatchArgs, stop: &AtomicBool) -> anyhow::Result<i32> {
        let opts = crate::ros2::watch::WatchOptions {
            domain: args.domain,
            connect: args.connect.clone(),
            namespace: args.namespace.clone(),
            count: args.count,
        };
        crate::ros2::watch::watch(&opts, stop)
    }

    #[cfg(not(feature = "ros2"))]
    pub(crate) fn watch(_: &WatchArgs, _: &AtomicBool) -> anyhow::Result<i32> {
        anyhow::bail!(NOT_BUILT)
    }
}

/// The fleet when built in, and what `--fleet` and `adrive fleet` say when it is not.
mod fleet {
    use super::FleetArgs;
    use crate::config::FleetConfig;
    use crate::engine::Gate;
    use crate::net::auth::Auth;
    use crate::socket::client::Dial;
    use std::path::Path;
    use std::sync::Arc;
    use std::time::Duration;

    #[cfg(not(feature = "fleet"))]
    const NOT_BUILT: &str = "this adrive was built without the fleet; build it with \
                             `cargo build --release --features fleet`";

    /// The running member, if the vehicle joined a fleet.
    #[cfg(feature = "fleet")]
    pub(crate) struct Running(Option<crate::fleet::Member>);
    #[cfg(not(feature = "fleet"))]
    pub(crate) struct Running;

    /// Join the fleet `c` as the vehicle named `vehicle`, if it joins one.
    #[cfg(feature = "fleet")]
    pub(crate) fn join(c: Option<&FleetConfig>, vehicle: &str) -> anyhow::Result<Running> {
        match c {
            None => Ok(Running(None)),
            Some(c) => Ok(Running(Some(crate::fleet::Member::join(c, vehicle)?))),
        }
    }

    #[cfg(not(feature = "fleet"))]
    pub(crate) fn join(c: Option<&FleetConfig>, _: &str) -> anyhow::Result<Running> {
        if c.is_some() {
            anyhow::bail!("--fleet or [fleet]: {NOT_BUILT}");
        }
        Ok(Running)
    }

    impl Running {
        /// Publish the vehicle's state, once it runs.
        pub(crate) fn publish(&mut self, gate: &Arc<Gate>) -> anyhow::Result<()> {
            #[cfg(feature = "fleet")]
            if let Some(m) = &mut self.0 {
                m.publish(gate.clone())?;
            }
            let _ = gate;
            Ok(())
        }

        /// Take links from the fleet to the control socket `control`, proving `key`.
        pub(crate) fn serve(
            &mut self,
            control: &crate::socket::Server,
            key: Option<Auth>,
        ) -> anyhow::Result<()> {
            #[cfg(feature = "fleet")]
            if let Some(m) = &mut self.0 {
                return m.serve(control.door(), key);
            }
            let _ = (control, key);
            Ok(())
        }
    }

    impl crate::threads::Shutdown for Running {
        /// Leave the fleet; the names of the threads that did not stop.
        fn shutdown(self, deadline: Duration) -> Vec<String> {
            #[cfg(feature = "fleet")]
            if let Some(m) = self.0 {
                return m.shutdown(deadline);
            }
            let _ = deadline;
            Vec::new()
        }
    }

    /// `adrive fleet`.
    #[cfg(feature = "fleet")]
    pub(crate) fn list(args: &FleetArgs) -> anyhow::Result<i32> {
        for e in &args.connect {
            crate::config::ros2::check_endpoint(e)
                .map_err(|why| anyhow::anyhow!("--connect: {why}"))?;
        }
        if args.pick {
            return pick(args);
        }
        if args.router {
            let listen = if args.listen.is_empty() {
                vec![crate::fleet::router::DEFAULT_LISTEN.to_string()]
            } else {
                args.listen.clone()
            };
            for e in &listen {
                crate::config::ros2::check_endpoint(e)
                    .map_err(|why| anyhow::anyhow!("--listen: {why}"))?;
            }
            let stop = super::stop_flag()?;
            return crate::fleet::router::run(&listen, &stop);
        }
        let opts = crate::fleet::list::Options {
            connect: args.connect.clone(),
            wait: args.wait,
            watch: args.watch,
            json: args.json,
        };
        let stop = super::stop_flag()?;
        crate::fleet::list::run(&opts, &stop)
    }

    /// `adrive fleet --pick`.
    #[cfg(feature = "fleet")]
    fn pick(args: &FleetArgs) -> anyhow::Result<i32> {
        use crate::console;
        let keymap = console::keymap::Keymap::for_run(args.keymap.as_deref())?;
        let key = match args.key.as_deref() {
            Some(k) => {
                crate::paths::check_file("--key", k).map_err(anyhow::Error::msg)?;
                Some(Auth::load(k).map_err(|e| anyhow::anyhow!("--key {e}"))?)
            }
            None => None,
        };
        console::terminal::check_standard_streams(console::terminal::ATTACH_WITHOUT)
            .map_err(anyhow::Error::msg)?;
        let exits = crate::exit::install()?;
        let opts = crate::fleet::pick::Options {
            connect: args.connect.clone(),
            key,
            key_file: args.key.as_ref().map(|k| k.display().to_string()),
            keymap,
            deadman: args
                .deadman
                .unwrap_or(crate::config::limits::DEADMAN_DEFAULT),
        };
        let why = crate::fleet::pick::run(&opts, &exits)?;
        if let crate::exit::Exit::HangUp(_) = why {
            super::tell(
                std::io::stderr(),
                format_args!("adrive: {}\n", why.describe()),
            );
        }
        Ok(crate::exit::status(&why, true, true))
    }

    #[cfg(not(feature = "fleet"))]
    pub(crate) fn list(_: &FleetArgs) -> anyhow::Result<i32> {
        anyhow::bail!("fleet: {NOT_BUILT}")
    }

    /// The way to vehicle `id` of the fleet (`--vehicle`), through `connect`, proving
    /// the key in `key` if given: each option checked, named.
    #[cfg(feature = "fleet")]
    pub(crate) fn dialer(
        connect: &[String],
        id: &str,
        key: Option<&Path>,
    ) -> anyhow::Result<Arc<dyn Dial>> {
        for e in connect {
            crate::config::ros2::check_endpoint(e)
                .map_err(|why| anyhow::anyhow!("--connect: {why}"))?;
        }
        if !crate::config::fleet::valid_id(id) {
            anyhow::bail!(
                "--vehicle: expected {}, got {id:?}",
                crate::config::fleet::ID_FORM
            );
        }
        let key = match key {
            Some(k) => {
                crate::paths::check_file("--key", k).map_err(anyhow::Error::msg)?;
                Some(Auth::load(k).map_err(|e| anyhow::anyhow!("--key {e}"))?)
            }
            None => None,
        };
        Ok(Arc::new(crate::fleet::dial::Dialer {
            connect: connect.to_vec(),
            id: id.to_string(),
            key,
            links: parking_lot::Mutex::default(),
        }))
    }

    #[cfg(not(feature = "fleet"))]
    pub(crate) fn dialer(_: &[String], _: &str, _: Option<&Path>) -> anyhow::Result<Arc<dyn Dial>> {
        anyhow::bail!("--vehicle: {NOT_BUILT}")
    }
}

/// How many received commands `adrive sim` holds while its output is slow; past
/// that they are counted and said, never kept (its memory stays flat).
const SIM_BACKLOG: usize = 4096;

/// `adrive sim`: the simulated devices alone. Everything it prints goes through one
/// writer: a standard output closed by its reader (`adrive sim | head`) ends it
/// quietly, its links removed.
pub fn sim(args: SimArgs) -> anyhow::Result<i32> {
    let config = load(&args.config, &args.only)?;
    let (tx, mut rx) = crossbeam_channel::bounded::<SimEvent>(SIM_BACKLOG);
    let sim = Sim::start(&config, (!args.quiet).then_some(tx))?;
    if args.quiet {
        // Nothing will ever come (the sender went with `None`): a disconnected
        // receiver is always ready, and selecting on it would spin a core.
        rx = crossbeam_channel::never();
    }
    // Applied before any port is printed, so no host sees the device without them;
    // confirmed below, as the same line typed is.
    let mut applied = Vec::new();
    for f in &args.fault {
        applied.push(
            sim.apply(f)
                .map_err(|e| anyhow::anyhow!("--fault {f:?}: {e}"))?,
        );
    }
    let exits = exit::install()?;
    let mut out = io::stdout().lock();
    let width = sim
        .ports
        .iter()
        .chain(&sim.buses)
        .map(|p| p.name.len())
        .max()
        .unwrap_or(6)
        .max(6);
    for p in &sim.ports {
        let d = config.device(&p.name).expect("simulated from the config");
        writeln!(
            out,
            "{:<width$} {}  -> {}  ({}, {} baud)",
            p.name,
            p.path,
            p.pty.lock(),
            d.driver,
            d.baud
        )?;
    }
    for (i, p) in sim.buses.iter().enumerate() {
        let on: Vec<&str> = config
            .devices
            .iter()
            .filter(|d| matches!(&d.wire, config::protocol_map::Wire::Can(m) if m.bus == i))
            .map(|d| d.name.as_str())
            .collect();
        writeln!(
            out,
            "{:<width$} {}  -> {}  ({}, {} bit/s: an OSCC kit with {})",
            p.name,
            p.path,
            p.pty.lock(),
            crate::config::device::DriverKind::Can,
            config.buses[i].bitrate.bits_per_second(),
            on.join(", ")
        )?;
    }
    for done in &applied {
        writeln!(out, "{done}")?;
    }
    // Examples this vehicle takes: a port of its own, and its e-stop when it has one.
    let mut examples: Vec<String> = sim
        .ports
        .iter()
        .chain(&sim.buses)
        .take(1)
        .map(|p| format!("`silent {} on`", p.name))
        .collect();
    if sim.names().has.estop {
        examples.push("`estop pause`".into());
    }
    examples.push("…".into());
    writeln!(
        out,
        "type `help` for the faults and events it takes ({}); Ctrl-C stops",
        examples.join(", ")
    )?;
    let (lines_tx, mut lines) = crossbeam_channel::unbounded::<String>();
    std::thread::Builder::new()
        .name("sim/stdin".into())
        .spawn(move || {
            for line in std::io::stdin().lock().lines().map_while(Result::ok) {
                if lines_tx.send(line).is_err() {
                    break;
                }
            }
        })?;
    let reader_gone = output_closed()?;
    let start = Instant::now();
    let mut dropped = 0;
    let why = loop {
        crossbeam_channel::select! {
            recv(exits) -> why => break why.unwrap_or(Exit::Quit),
            // `adrive sim | head`: the reader left, and nothing more can be said.
            recv(reader_gone) -> _ => break Exit::HangUp("its output was closed".into()),
            recv(rx) -> ev => if let Ok(ev) = ev {
                let now = sim.dropped_events();
                if now > dropped {
                    writeln!(out, "… {} commands not shown: the output was too slow", now - dropped)?;
                    dropped = now;
                }
                let at = ev.at.duration_since(start).as_secs_f64();
                match &ev.note {
                    // The device acted on its own: nothing arrived.
                    Some(note) => writeln!(out, "{at:>9.3}s {:<width$}    {note}", ev.name)?,
                    None => writeln!(
                        out,
                        "{at:>9.3}s {:<width$} <- {:<10} {}",
                        ev.name,
                        ev.text,
                        printable(&ev.request)
                    )?,
                }
            },
            recv(lines) -> line => match line {
                Ok(line) if line.trim().is_empty() => {}
                Ok(line) => match sim.apply(&line) {
                    Ok(done) => writeln!(out, "{done}")?,
                    Err(e) => writeln!(out, "error: {e}")?,
                },
                // Standard input closed (`< /dev/null`, a service): keep serving and
                // printing until a signal.
                Err(_) => lines = crossbeam_channel::never(),
            },
        }
    };
    tracing::debug!("sim stopping: {}", why.describe());
    // Dropping the simulator closes the ports and removes its directory of links.
    drop(sim);
    Ok(0)
}

/// A message once standard output's reader has gone (a pipe whose reader closed, as
/// `adrive sim | head` does once it has its lines; a terminal hung up): at once, not
/// at the next write, which may never come. Never, where it cannot be told (standard
/// output a file).
fn output_closed() -> io::Result<crossbeam_channel::Receiver<()>> {
    use rustix::event::{PollFd, PollFlags};
    let (tx, rx) = crossbeam_channel::bounded(1);
    std::thread::Builder::new()
        .name("sim/stdout".into())
        .spawn(move || {
            let out = rustix::stdio::stdout();
            // No events asked: poll reports only the error and the hang-up, always.
            let mut fds = [PollFd::new(&out, PollFlags::empty())];
            loop {
                match rustix::event::poll(&mut fds, None) {
                    Ok(_) if fds[0].revents().intersects(PollFlags::ERR | PollFlags::HUP) => {
                        let _ = tx.send(());
                        return;
                    }
                    Ok(_) if fds[0].revents().is_empty() => continue,
                    Err(rustix::io::Errno::INTR) => continue,
                    // Closed (`>&-`: NVAL), or poll failed: nothing to watch.
                    Ok(_) | Err(_) => return,
                }
            }
        })?;
    Ok(rx)
}

/// Bytes as text, with non-printable bytes escaped.
pub(crate) fn printable(bytes: &[u8]) -> String {
    bytes.escape_ascii().to_string()
}

/// `adrive record info`: what a recording holds.
pub(crate) fn record_info(file: &Path) -> anyhow::Result<i32> {
    paths::check_file("", file).map_err(anyhow::Error::msg)?;
    let rec = record::read::Recording::open(file)?;
    tell(io::stdout(), format_args!("{}", record::info::report(&rec)));
    Ok(0)
}

/// `adrive record repair`: a finished copy of a recording that was not finished.
pub(crate) fn record_repair(file: &Path, out: Option<&Path>) -> anyhow::Result<i32> {
    paths::check_file("", file).map_err(anyhow::Error::msg)?;
    if let Some(out) = out {
        paths::check_new_file("--out", out).map_err(anyhow::Error::msg)?;
    }
    let rec = record::read::Recording::open(file)?;
    let state = record::info::state(&rec, None);
    if rec.complete && !rec.writing {
        tell(
            io::stdout(),
            format_args!("{}: {state}: nothing to repair\n", file.display()),
        );
        return Ok(0);
    }
    let out = out.map_or_else(|| record::repair::beside(file), Path::to_path_buf);
    let r = record::repair::repair(&rec, &out, &state)?;
    tell(
        io::stdout(),
        format_args!(
            "{}: {state}\nwrote {}: {} messages on {} channels, finished (summary and index)\n",
            file.display(),
            r.out.display(),
            r.messages,
            r.channels
        ),
    );
    Ok(0)
}

/// `adrive export FILE --csv DIR`: one CSV per channel.
pub fn export(args: ExportArgs) -> anyhow::Result<i32> {
    paths::check_file("", &args.file).map_err(anyhow::Error::msg)?;
    let rec = record::read::Recording::open(&args.file)?;
    paths::create_dir("--csv", &args.csv).map_err(anyhow::Error::msg)?;
    for (path, rows) in record::export::csv(&rec, &args.csv)? {
        tell(
            io::stdout(),
            format_args!("{:>9} rows  {}\n", rows, path.display()),
        );
    }
    if let Some(why) = &rec.cut {
        tell(
            io::stderr(),
            format_args!(
                "adrive export: {}: cut off ({why}); exported up to its last whole chunk\n",
                args.file.display()
            ),
        );
    }
    Ok(0)
}

/// `adrive replay FILE`: the console plays a recording (or, headless, broadcasts it).
pub fn replay(args: ReplayArgs) -> anyhow::Result<i32> {
    paths::check_file("", &args.file).map_err(anyhow::Error::msg)?;
    let rec = record::read::Recording::open(&args.file)?;
    if let Some(vehicle) = &args.check {
        let config = config::load(vehicle)?;
        let report = record::check::check(&rec, &config);
        // The status tells the outcome, read or not (`| head`).
        let _ = io::stdout().write_all(
            report
                .render(
                    &args.file.display().to_string(),
                    &vehicle.display().to_string(),
                )
                .as_bytes(),
        );
        return Ok(report.status());
    }
    let mut player = console::replay::Player::load(&rec).map_err(anyhow::Error::msg)?;
    drop(rec);
    if let Some(x) = args.speed {
        if !(0.125..=32.0).contains(&x) {
            anyhow::bail!("--speed: expected 0.125 to 32, got {x}");
        }
        player.set_speed(x, Instant::now());
    }
    let keymap = if args.headless {
        None
    } else {
        let keymap = console::keymap::Keymap::for_run(args.keymap.as_deref())?;
        console::terminal::check_standard_streams(console::terminal::REPLAY_WITHOUT)
            .map_err(anyhow::Error::msg)?;
        Some(keymap)
    };
    let broadcast = match args.broadcast.is_empty() {
        true => None,
        false => Some(console::replay::Broadcast::new(args.broadcast.clone())?),
    };
    let log = logging::init(args.headless, None)?;
    let exits = exit::install()?;
    let why = match (keymap, broadcast) {
        (None, Some(b)) => {
            // Headless, nothing else would say what is played and where.
            let to = args
                .broadcast
                .iter()
                .map(ToString::to_string)
                .collect::<Vec<_>>()
                .join(", ");
            let n = player.len();
            // A closed standard output does not stop the replay.
            let _ = writeln!(
                io::stdout(),
                "replaying {}: {n} snapshots over {:.1} s, to {to} at ×{}",
                args.file.display(),
                player.seconds().1,
                player.speed()
            );
            let (why, sent) = console::replay::headless(player, &exits, &b);
            let _ = writeln!(io::stdout(), "sent {sent} of {n} snapshots to {to}");
            why
        }
        (Some(keymap), b) => console::replay::run(player, keymap, &exits, b)?,
        (None, None) => unreachable!("clap requires --broadcast with --headless"),
    };
    drop(log);
    Ok(exit::status(&why, true, true))
}
