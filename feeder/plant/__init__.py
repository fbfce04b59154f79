"""The physical plant: amplifier limits → piezo stack + plate → part stick-slip (DESIGN §4).

API for other agents
--------------------
Streaming plant (firmware_sim/world.py)::

    from feeder.plant.plant import Plant
    from feeder.plant.stick_slip import Friction
    plant = Plant(Friction(static_accel_m_s2=105.0, kinetic_ratio=0.8),
                  amplifier=AmplifierLimits(), stack=StackParameters(),
                  sample_rate_hz=100e3, scatter=0.05, seed=1, initial_v=0.0)
    # or from the contact model ("true" τ may differ from the host's nominal):
    plant = Plant.from_contact(part, support, surface, tau_pa=20e9, kinetic_ratio=0.8,
                               sample_rate_hz=100e3, scatter=0.05, seed=1)
    x = plant.advance(command_volts)   # np.ndarray of DAC command samples (V) → part x (m) per sample
    plant.part_position_m, plant.plate_position_m, plant.output_voltage_v  # state after the chunk
    plant.advance_traces(cmd)          # → (part x, plate x) per sample

- ``command_volts``: the command voltage the DAC asks for (any chunk length,
  e.g. 100 samples per 1 ms tick); the amplifier then applies rails, slew and
  current limit (:mod:`.amplifier`), the stack + plate filter it (:mod:`.stack`),
  the part sticks or slips (:mod:`.stick_slip`).  State carries across calls.
- ``scatter``: relative std of a_s, redrawn at every re-stick (step-to-step spread).
- Large chunks are the fast path (≥ 100 simulated s per wall s); 1 ms chunks cost
  mostly per-call overhead.

Other pieces: :func:`feeder.plant.plant.run_waveform` (a waveform for N
periods → per-step displacements), :mod:`.ideal_plate` (plate following the
waveform exactly, closed form for the linear flyback),
:func:`.stick_slip.simulate_batch` (many parameter sets at once).
"""
