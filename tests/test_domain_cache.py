"""The per-process domain cache: one domain per configuration, and the simulator clients of
the domains it drops or closes are disconnected."""

import pybullet as pb

from pipeline.domains.cache import DomainCache


def spec(name: str, **config) -> dict:
    return {"name": name, "config": config, "planner": {"name": "rrt_connect"}}


def connected(client: int) -> bool:
    return bool(pb.getConnectionInfo(physicsClientId=client)["isConnected"])


def test_the_cache_reuses_domains_and_closes_the_clients_it_drops():
    cache = DomainCache(size=1)
    arm = cache.get(spec("grasp_arm"))
    assert cache.get(spec("grasp_arm")) is arm and len(cache) == 1
    arm.plan(arm.sample_instance(0), 0, seed=0)
    client = arm.scene(arm.check_instance(arm.sample_instance(0))).client_id
    assert connected(client)
    planar = cache.get(spec("planar", obstacles_max=5))  # pushes grasp_arm out
    assert len(cache) == 1 and not connected(client)
    assert cache.get(spec("planar", obstacles_max=5)) is planar
    assert cache.get(spec("planar", obstacles_max=6)) is not planar


def test_closing_the_cache_disconnects_every_client_and_a_new_domain_works():
    cache = DomainCache()
    arm = cache.get(spec("grasp_arm"))
    inst = arm.check_instance(arm.sample_instance(0))
    before = arm.plan(inst, 40, seed=1)
    client = arm.scene(inst).client_id
    cache.close()
    assert len(cache) == 0 and not connected(client)
    again = cache.get(spec("grasp_arm"))
    assert again is not arm
    after = again.plan(inst, 40, seed=1)
    assert (after.status, after.checks, repr(after.score)) == (before.status, before.checks,
                                                               repr(before.score))
