"""crowdplan: robot navigation among dense crowds with representation learning + discrete SAC."""

from gymnasium.envs.registration import register, registry

__version__ = "0.1.0"

ENV_IDS = {
    "crowdplan/CircleCrossing-v0": "circle_crossing",
    "crowdplan/SquareCrossing-v0": "square_crossing",
}

for _env_id, _scenario in ENV_IDS.items():
    if _env_id not in registry:
        register(
            id=_env_id,
            entry_point="crowdplan.sim.env:CrowdNavEnv",
            # gymnasium.make_vec(id, num_envs=E) gives the native batched env over one World
            vector_entry_point="crowdplan.sim.env:CrowdNavVectorEnv",
            kwargs={"scenario": _scenario},
        )
