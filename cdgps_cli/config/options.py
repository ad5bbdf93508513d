"""Every option default in one place (as python-control's ``config.defaults``).

The library's option classes (:class:`~cdgps_cli.estimation.batch_init.InitOptions`,
:class:`~cdgps_cli.estimation.baseline.BaselineOptions`, the GNSS run config), the LAMBDA functions
and the command line all read their defaults from here, so a default is changed in one line and the
help texts say the same number.  Plausible ranges of options are in :mod:`cdgps_cli.config.limits`.
"""

from __future__ import annotations

#: LAMBDA ratio test (second-best over best squared norm) for accepting an integer set, init and GNSS
RATIO_THRESHOLD = 3.0
#: cold start of the structure initializer: initial guesses of the rigid angle (or lowest mode)
INIT_STARTS = 8
#: Gauss–Newton iteration cap of the structure initializer
INIT_MAX_ITERATIONS = 30
#: un-differenced phase σ = a + b / sin(elevation) (m), RTKLIB's form
PHASE_SIGMA_A_M = 0.003
PHASE_SIGMA_B_M = 0.003
#: the modal batch initialization on GNSS also uses pseudorange DDs (σ = code_ratio × the phase σ)
MODAL_INIT_CODE_DD = True
#: prior 1σ of the modal positions (config units) and rates (/s) about 0 at the first epoch, beyond the
#: stationary spread of the process noise: a record need not start in the stationary state
MODAL_INITIAL_SIGMA_XI = 1.0
MODAL_INITIAL_SIGMA_XIDOT = 1.0

#: GNSS run config and baseline solver defaults (docs/gnss-pipeline.md)
#: the DD ionosphere is neglected on baselines shorter than this, km (`cdgps rtk` estimates it at or
#: above; `cdgps init` with [gnss] signals, which always neglects it, refuses there: gnss.iono_threshold_km)
IONO_THRESHOLD_KM = 10.0
#: the static engine's option ``iono_weighted`` (off by default; static_engine.iono_weighting_sigma_m) weighs the
#: ionosphere in the float LAMBDA sees: one SD slant ionosphere per satellite, 0 ± ``iono_sigma_m_per_km`` × length,
#: once that σ reaches this (m; 0.5 km at 2 mm/km; below, its effect is under a third of the phase σ)
IONO_WEIGHTED_MIN_SIGMA_M = 0.001
#: the static engine (`init`, `baseline`) rejects its integers when, with them, each epoch's carrier phases solved
#: alone for a position leave a unit variance above this (≈ 1 when they are right; 0.14–0.79 on the real pairs'
#: fixes; the GPS L1+L2 car's wrong partial fix 11, a wrong full one 72): the float LAMBDA saw was biased beyond
#: its σ (correlated code multipath, an unmodelled ionosphere, a slip the receiver did not flag)
FIXED_PHASE_UNIT_VARIANCE_MAX = 4.0
#: … or when, over any window of this many seconds (with 20 DDs to spare), it is above the second figure: a wrong
#: integer on a short arc, which a long record's mean dilutes.  The real pairs' fixes: 0.14–2.7 over 120 s windows
#: (M8P 1.5; 4.5 over 30 s windows); the car's wrong partial fix 11.6, the M8P 1 ms clock jump's 8.3
FIXED_PHASE_WINDOW_S, FIXED_PHASE_WINDOW_UNIT_VARIANCE_MAX = 120.0, 8.0
#: integers no epoch's phases can check (each epoch has fewer than four DDs of fixed arcs) are not taken from a
#: moving rover's random-walk float whose NIS per SD row is above this (≈ 0.9 when the walk holds the motion; the
#: real pairs under a walk that does: 0.1–1.8; p9's walker under 1 mm/√s 8 900 (8 integers), the GEONET car
#: 2.7·10⁵ (3 integers, which the raised float confirms; 44 of 44 fixed under 1 m/√s)): LAMBDA's ratio and success rate
#: trust a Q too small by about as much, so such integers cannot be judged, not that they are wrong
UNCHECKED_FIX_NIS_MAX = 10.0
#: … and a random-walk float above it is solved again with its σ raised by this factor, at most this many times
#: (1 mm/√s → 10 m/√s), before LAMBDA sees it: the first σ whose NIS is not above it gives the float (p9's walker
#: 8 900 → 171 → 5.5 at 0.1 m/√s; the car 2.7·10⁵ → … → 1.8 at 1 m/√s, 44 of 44 integers fixed and checked)
RANDOM_WALK_RAISE_FACTOR, RANDOM_WALK_MAX_RAISES = 10.0, 4

#: a step of a signal group's SD codes against its phases at least this large, m, common to the group's channels
#: between two epochs, is a receiver clock jump in the codes alone (1 ms: 299.8 km), which the static engine's arc
#: prior removes (static_engine.code_clock_steps); code multipath and the ionosphere change (code − phase) by
#: centimetres to a metre from one epoch to the next
CODE_CLOCK_STEP_MIN_M = 30.0

#: pairing base epochs with rover epochs (measurement/epoch_pairing.py), every GNSS command:
#: ``sync_tol_s`` a base epoch this close to a rover epoch is simultaneous (RTKLIB's DTTOL, 25 ms);
#: ``max_age_s`` the oldest base epoch bridged across a base gap (RTKLIB's ``pos2-maxage`` default, 30 s);
#: ``age_sigma_m_per_s`` the σ an SD observation gains per second of base age (RTKLIB's satellite-clock
#: stability ``stats-clkstab`` 5·10⁻¹² s/s × c = 1.5 mm/s)
EPOCH_PAIRING_DEFAULTS = {"sync_tol_s": 0.025, "max_age_s": 30.0, "age_sigma_m_per_s": 5e-12 * 299792458.0}

#: the rover's troposphere is computed at its a-priori position (RINEX APPROX POSITION XYZ or a
#: single-point position); a solution this far (m) from it moves the origin there and solves again (the
#: hydrostatic delay changes ≈ 0.3 mm per metre of height, about 1 mm of height per metre at a 15° mask;
#: RTKLIB evaluates it at its current estimate: a header 17.5 m high put the GEONET car +13 mm above it)
ROVER_ORIGIN_TOL_M = 1.0

#: a static float solution this far (m) from the least squares of the code alone is not where the rover is: it moves
#: (a static rover's two agree to about a metre, the code's multipath; a 40 m walk put the static float 789 m away, a
#: 30 m walk of a 2010 u-blox rover 774 m): ``rtk`` then starts from the code's mean position, and so does ``init``'s
#: random-walk float
MOVING_ROVER_FLOAT_M = 20.0

#: an offset is taken as where the rover is only when it exceeds this many times its 3-D σ (√trace of its covariance):
#: two satellites over ten minutes of a 35 km pair gave a static float 14.6 m away with σ of tens of metres
ORIGIN_MOVE_SIGMAS = 3.0

#: variance factor of a GLONASS (FDMA) code single difference while GLONASS is float (not glonass_fix): the
#: receivers' code biases differ from channel to channel and do not cancel (u-blox: decimetres to metres), so the
#: GLONASS codes weigh 10×σ less than the others.  On the real M8P pair with a random-walk float they pulled the GPS
#: floats 0.1–0.2 cycle off (2 of 68 integers fixed; 23 with this factor, as many as the static model fixes)
GLONASS_FLOAT_CODE_VARIANCE_FACTOR = 100.0

#: ``estimate`` on a GNSS run warns when the mean NIS per degree of freedom of its DDs is above this (≈ 1 when the
#: model holds): the real pairs give 0.002–0.8 (static) and 0.45–4.4 (constant velocity, a u-blox walk with 8 of
#: 217 integers); a car on the Spirent simulator under a 1 mm/√s random walk gave 5·10⁵, a simulated rover wandering
#: 5 m under one 8·10², both without a word before
NIS_MISFIT_PER_DOF = 10.0

#: the phase weightings of every GNSS solver: SD variance a² + b²/sin²(el) or a² + b² per receiver
#: (measurement/differencing.sd_variance)
GNSS_WEIGHTINGS = ("elevation", "equal")

#: code_noise "auto" (measurement/noise.code_noise_factor): the window over which the code errors' mean is
#: compared with the model's (s), the chunks each arc's code-minus-carrier is detrended over (s), and the fewest
#: full windows for an estimate (fewer: the model's variance, factor 1), and the smallest factor applied
CODE_NOISE_WINDOW_S, CODE_NOISE_CHUNK_S, CODE_NOISE_MIN_WINDOWS, CODE_NOISE_MIN_FACTOR = 30.0, 300.0, 10, 1.5

#: phase_noise "auto" (pipeline/gnss.phase_variance_factor): the fewest degrees of freedom of the single-epoch
#: solutions' DD phase residuals a factor is estimated from (fewer: the model's variances, factor 1)
PHASE_NOISE_MIN_DOF = 100

GNSS_DEFAULTS = {"mask_deg": 15.0, "ratio": RATIO_THRESHOLD, "partial": True, "weighting": "elevation",
                 "troposphere": True, "sigma_a_m": PHASE_SIGMA_A_M, "sigma_b_m": PHASE_SIGMA_B_M,
                 "code_ratio": 100.0, "sync_tol_s": EPOCH_PAIRING_DEFAULTS["sync_tol_s"],
                 "max_age_s": EPOCH_PAIRING_DEFAULTS["max_age_s"], "epoch_alignment": "geometry",
                 "code_correlation_s": 0.0,
                 "random_walk_sigma": (0.001, 0.001, 0.001), "initial_sigma_m": 1.0,
                 # [gnss.displacement] model = "constant_velocity": each E/N/U velocity a random walk of this
                 # density (white acceleration, m/s/√s); a structure's few-mm motion, not a vehicle's (rtk: 3.0)
                 "accel_sigma_m_per_s_per_sqrt_s": 0.1,
                 # estimate's per-epoch states: the phase variances as modelled ("model"), or scaled by the unit
                 # variance of the single-epoch solutions' DD phase residuals ("auto")
                 "phase_noise": "model",
                 # estimate's per-epoch states: white phase errors ("off"), or a Gauss–Markov multipath state per
                 # satellite and signal, fitted ("auto") or given ("model"; its time constant by default 30 s)
                 "multipath": "off", "multipath_time_constant_s": 30.0,
                 "iono_threshold_km": IONO_THRESHOLD_KM,
                 # an integer set (or partial subset) is fixed only if its bootstrapped success rate reaches this,
                 # besides the ratio test (partial ambiguity resolution with a success-rate criterion)
                 "min_success_rate": 0.999,
                 # GLONASS double differences fixed as integers: only between identical receivers (their
                 # inter-frequency biases cancel); otherwise GLONASS ambiguities stay float
                 "glonass_fix": False}

#: `cdgps control design` weights by default: "paper", the 1998 paper's Sec. V numbers
#: (Q_x* = 5000 diag(1, …, 1, 0.01), Q_x = diag(Q_x*, 0.01 Q_x*), Q_u = I; cdgps_cli.control.lqr.PAPER_*)
CONTROL_WEIGHTS = "paper"
#: `--weights tuned`: the paper's weight form with the numbers its tuning rule ("the maximum control
#: authority that could be applied without saturating the actuators") gives on our thruster model Υ,
#: used by the experiments (docs/control.md "Which weights")
CONTROL_TUNED_WEIGHTS = {"qx": 100.0, "rigid_factor": 0.3, "rate_factor": 0.1}

#: the simulators' master receiver, ECEF (m): GEONET 3040's position, so simulated runs look like the real pair
SIM_MASTER_ECEF_M = (-3978242.4348, 3382841.1715, 3649902.7667)


def toml_value(v) -> str:
    """A default as TOML text (for the starter configs the commands write)."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return f'"{v}"'
    return repr(float(v)) if isinstance(v, float) else str(v)

#: multi-GNSS dual-frequency RTK (estimation/rtk_multi.py, docs/gnss-pipeline.md "Multi-GNSS")
def default_direction(mode: str) -> str:
    """rtk's passes when none is given: static mode one forward pass (RTKLIB's static default, its last epoch uses
    them all), the other modes forward and backward combined."""
    return "forward" if mode == "static" else "combined"


MULTI_GNSS_DEFAULTS = {
    "signals": "auto",                     # every signal both files hold whose system has ephemerides, or a tuple of names
    "mode": "kinematic",                   # "kinematic" (random-walk position), "constant-velocity" or "static"
    "direction": None,                     # "forward", "backward" or "combined" (both, checked against each other); None: the mode's (default_direction)
    "kinematic_sigma_m_per_sqrt_s": 30.0,  # random-walk rate of the kinematic rover position
    "accel_sigma_m_per_s_per_sqrt_s": 3.0,  # constant-velocity mode: velocity random walk (white acceleration; RTKLIB's stats-prnaccelh)
    "mask_deg": 15.0, "ratio": RATIO_THRESHOLD, "fix": True, "glonass_fix": GNSS_DEFAULTS["glonass_fix"],
    "min_success_rate": GNSS_DEFAULTS["min_success_rate"],  # bootstrapped success rate an integer set must reach (partial set otherwise)
    "code_correlation_s": GNSS_DEFAULTS["code_correlation_s"],  # code errors as a Gauss-Markov process of this correlation time, s (0: white)
    # "auto": the code variance scaled by what the files' own code-minus-carrier shows over CODE_NOISE_WINDOW_S
    # (measurement/noise.code_noise_factor; a u-blox M8P: 39, geodetic receivers ≈ 1); "model": as modelled
    "code_noise": "auto",
    # "auto": the σ a bridged base observation gains per second of age is what the base's own observations minus
    # their model do over that age (measurement/base_interpolation.base_drift_m_per_s), at least age_sigma_m_per_s
    # (RTKLIB's 1.5 mm/s); "model": age_sigma_m_per_s alone.  Real bases: a 2008 Crescent 10 mm/s, mosaic 2.1,
    # the u-blox M8P 1.3, Leica CORS 0.9
    "age_noise": "auto",
    # feed fixed integers back as measurements (RTKLIB pos2-armode=fix-and-hold), checked by the wrong-fix test below:
    # the real car (geonet-car G+E L1) 181 -> 311 of 360 epochs fixed, none wrong where the answer is known
    # (benchmarks/fix_correctness.py, docs/benchmarks/fix_correctness.json)
    "fix_and_hold": True,
    "hold_after_fixes": 10,                # … once this many consecutive epochs fixed (RTKLIB pos2-arminfix)
    "wrong_fix_probability": 0.999,        # while holding: an epoch's NIS above χ²(this) of its DDs resets the ambiguities to float (0: off)
    "sigma_a_m": PHASE_SIGMA_A_M, "sigma_b_m": PHASE_SIGMA_B_M, "code_ratio": 100.0,
    "weighting": GNSS_DEFAULTS["weighting"],  # SD variance a² + b²/sin²(el) ("elevation") or a² + b² ("equal"), per receiver
    "amb_sigma_cycles": 30.0, "troposphere": True,
    "iono_threshold_km": IONO_THRESHOLD_KM,  # below: DD ionosphere neglected; above: estimated
    "pos_frame": "llh",                    # a .pos output's coordinates: "llh", "xyz" (ECEF) or "enu" (baseline; RTKLIB out-solformat)
    "iono_sigma_m_per_km": 0.002,          # prior σ of the SD slant ionosphere per km of baseline
    "iono_rw_m_per_sqrt_s": 0.0005,
    # the zenith wet delays of the base and the rover, estimated (states of the filter) on baselines at least this
    # long, km; neglected below (the a-priori hydrostatic troposphere alone, each receiver's own): their difference
    # biases a long baseline's height by decimetres, with a σ that does not say so.  None: iono_threshold_km's value,
    # so that the long-baseline model estimates both, as RTKLIB's ionoopt=est-stec with tropopt=est (estimating the
    # wet delays while the ionosphere is neglected gave DELF → ZEGV, 35 km, a wrong fix in both tools)
    "tropo_threshold_km": None,
    "tropo_initial_m": 0.15, "tropo_sigma_m": 0.3,      # their start and its σ at each receiver (RTKLIB's INIT_ZWD, std[2])
    "tropo_rw_m_per_sqrt_s": 1e-4,                       # their random walk (RTKLIB's stats-prntrop)
    # an ANTEX file (IGS .atx) whose receiver antenna calibrations (phase-centre offset and elevation variations, as
    # RTKLIB's antmodel) are taken out of the observations; None: none (the antennas' offsets differ by centimetres
    # between types, which a long baseline of mixed antennas shows in its height).  Each receiver's antenna is its
    # RINEX header's ANT # / TYPE unless named here ("none": no model for that receiver)
    "antex": None, "base_antenna": None, "rover_antenna": None,
    # the rover epochs solved, GPS s (RTKLIB's -ts / -te: a tag up to sync_tol_s before the start or less than that
    # after the end is in); None: from the record's first epoch or to its last.  The base is read max_age_s wider on
    # each side, where those epochs find their pairs
    "start_gps_s": None, "end_gps_s": None,
    **EPOCH_PAIRING_DEFAULTS,
}

#: a receiver's header position (APPROX POSITION XYZ) farther than this from its pseudorange single-point position,
#: m: a rover's is not used (headers are metres to tens of metres off; one 100 km off made init take the pair for a
#: 100 km baseline and refuse it); a base's or master's is refused (it would put every rover as far off: a Trimble
#: NetR9's RINEX 3.02 file 207 km off), by `rtk`, `baseline`, `init` and `estimate` alike
HEADER_POSITION_TOL_M = 1000.0
#: epochs (spread over the record) of the single-point position a header position is checked against
HEADER_CHECK_EPOCHS = 120

#: a receiver channel (satellite and signal) whose carrier phase is flagged lost-lock (LLI bit 0) at more than this
#: share of its epochs, over at least UNLOCKED_CHANNEL_MIN_EPOCHS, carries no phase: each flag starts a new
#: ambiguity.  `rtk` leaves it out (a warning names it).  A real rover's BeiDou B2I of three satellites flagged at
#: 91–96 % of 601 epochs kept every set holding B2I from fixing (0 of 601 epochs; 601 without those channels); the
#: real pairs' other channels flag at most 30 % (a satellite setting through the mask)
UNLOCKED_CHANNEL_SHARE = 0.5
#: largest change of a satellite's geometry-free phase combination (two signals' single-difference phases, m) between
#: consecutive epochs that `rtk` takes for ionosphere and noise, not a slip (measurement/slips.geometry_free_slips;
#: RTKLIB's pos2-slipthres)
GF_SLIP_THRESHOLD_M = 0.05
UNLOCKED_CHANNEL_MIN_EPOCHS = 20
#: a receiver channel whose carrier phase (m) runs opposite to its code (a receiver writing the phase with the wrong
#: sign: gnss-sdr 0.0.19 on a MAX2771 front end did, for some satellites of a run) is left out when, over pairs of its
#: epochs at least REVERSED_PHASE_LAG_S apart (at least REVERSED_PHASE_MIN_PAIRS of them), the median rate of code minus
#: phase exceeds REVERSED_PHASE_MIN_RATE_M_S (a right phase: ionospheric divergence, under 0.1 m/s, and code noise; a
#: reversed one: twice the range rate, up to 1.6 km/s) while the median rate of code plus phase stays below
#: REVERSED_PHASE_RATIO times it (a reversed phase: the code's noise alone), both rates taken about the receiver's
#: common code–carrier drift (measurement/phase_sign).  Channels near their closest approach (range rate near 0) give
#: no evidence either way and are kept.  (5 pairs: 5 s at 1 Hz, 2.5 min at 30 s)
REVERSED_PHASE_LAG_S, REVERSED_PHASE_MIN_PAIRS = 1.0, 5
REVERSED_PHASE_MIN_RATE_M_S, REVERSED_PHASE_RATIO = 5.0, 0.1

#: `cdgps estimate` (:class:`cdgps_cli.estimation.filter.EstimateOptions`): integrity tests and static mode
ESTIMATE_DEFAULTS = {
    "nis_probability": 0.999,          # chi-square level of the per-epoch NIS test
    "outlier_sigma": 6.0,              # |ν_i| / sqrt(S_ii) above this: suspected slip on channel i
    "process_noise_scale": 1.0,        # multiplies the config's process-noise σ (Q × scale²)
    "rest_process_noise_scale": 0.005,  # further factor inside rest segments
    "rest_retry_s": 1.0,               # after motion inside a rest segment, try rest again this much later, s
    "rest_window_s": 3.0,              # `--rest auto`: sliding window of the zero-velocity test, s
    "rest_dwell_s": 2.0,               # … and how long it must pass before rest is entered, s
}
#: `cdgps estimate --scene-exaggeration`: factor on the deformation drawn in STATES.mcap's 3-D scene
#: (/cdgps/scene, foxglove.SceneUpdate; cdgps_cli.analysis.scene); "auto": the largest of 1, 2, 5, 10, …
#: that draws the 99th-percentile deformation at most SCENE_AUTO_FRACTION of the structure's size; 0: no scene
SCENE_EXAGGERATION = "auto"
SCENE_AUTO_FRACTION = 0.05
#: the largest factor --scene-exaggeration takes (auto goes to 5e8): beyond, the drawn positions overflow to inf
SCENE_EXAGGERATION_MAX = 1e9
#: GNSS structure runs: the scene's satellite arrows (directions toward the satellites used) are taken every
#: this many seconds of the record (a GPS satellite moves about 0.08 deg in 10 s as seen from the ground)
SCENE_SKY_STEP_S = 10.0
#: epochs per chunk of the filter's history on disk (cdgps estimate): its pages are dropped from memory
#: chunk by chunk forward and backward (memory of a chunk, not of the record; the same numbers for any value).
#: An internal setting of the library (EstimateOptions.chunk_epochs), not a command-line option.
ESTIMATE_CHUNK_EPOCHS = 4096
#: bytes of open scratch files (the history on disk, the RUN's columns, packed arrays being written) a
#: process leaves in the page cache; past them each scratch file is written to disk and dropped from the
#: cache behind its writer (cdgps_cli.io.scratch.Behind): a short record costs no disk writes (the 1 h
#: testbed estimate peaks at 215 MiB), a day's record no more memory than this.  An internal setting,
#: not a command-line option.
SCRATCH_CACHE_BYTES = 512 << 20
#: structure frame on a GNSS run: azimuth of the structure's x axis, degrees from north (90: x = East)
X_AXIS_AZIMUTH_DEG = 90.0
#: `cdgps spectra` (:class:`cdgps_cli.analysis.spectra.SpectraOptions`): Welch segment overlap and FFT padding
SPECTRA_DEFAULTS = {"overlap": 0.5, "pad": 4}
#: epochs per chunk when `cdgps spectra` / `report spectrum` read a STATES.mcap (io.states.StatesChunks):
#: memory holds one chunk and its temporaries, whatever the record's length (16384 epochs of the
#: testbed's 10 coordinates: 1.3 MB of q); the results do not depend on it
STATES_CHUNK_EPOCHS = 16384
#: tracking loops (:class:`cdgps_cli.tracking.channel.TrackOptions`): PLL noise bandwidth (Hz) and FLL
#: pull-in (s) of `cdgps track` / `track-structure`
TRACK_DEFAULTS = {"pll_bn_hz": 15.0, "pull_in_s": 0.1}
#: samples read, converted and tracked at a time by `cdgps track` / `track-structure` (the IF file is
#: read in blocks of this many samples in its native type): 2^19 samples are 8 MiB as complex128,
#: 0.13 s at 4 MHz; results do not depend on it (tests/tracking/test_streaming.py)
TRACK_BLOCK_SAMPLES = 1 << 19
#: epochs of a RINEX observation body converted at a time by io.rinex.read_rinex_obs (its fast path):
#: 4096 epochs of ~40 satellite records are ~2.6 MB of field bytes and their temporaries; the table
#: does not depend on it (tests/io/test_rinex_body.py)
RINEX_BLOCK_EPOCHS = 4096
