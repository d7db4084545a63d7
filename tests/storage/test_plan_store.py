"""The PlanStore contract, run against every backend (``conftest.PLAN_BACKENDS``)."""

import threading

import pytest

from neuenh_service.storage import ConflictError, IllegalTransitionError, InvalidRecordError, NotFoundError, PlanStatus

SCENE = {"materials": [{"path": "a.npz"}], "ladder": ["ggx"]}


class TestPlanStore:
    def test_a_plan_walks_queued_running_done_and_keeps_its_materials_across_handles(self, plan_backend):
        store = plan_backend.open()
        plan, created = store.create_plan(SCENE, owner="ana")
        assert created and plan.status is PlanStatus.QUEUED and plan.materials_total is None
        assert store.unfinished_plans() == [plan]
        store.start(plan.id, 2)
        store.record_material(plan.id, "felt", {"chosen": "ggx"})
        again = plan_backend.open()  # a restarted service
        assert again.get_plan(plan.id).materials_done == 1 and again.get_plan(plan.id).status is PlanStatus.RUNNING
        assert again.planned_materials(plan.id) == {"felt": {"chosen": "ggx"}}
        again.start(plan.id, 2)  # resumed: RUNNING again is fine
        again.record_material(plan.id, "felt", {"chosen": "nbrdf"})  # a re-planned material keeps its first result
        again.record_material(plan.id, "silk", {"chosen": "ggx"})
        assert list(again.planned_materials(plan.id)) == ["felt", "silk"]
        assert again.planned_materials(plan.id)["felt"] == {"chosen": "ggx"}
        done = again.finish(plan.id, {"totals": {"plan": 1.0}})
        assert done.terminal and done.result == {"totals": {"plan": 1.0}} and done.materials_done == 2
        assert store.unfinished_plans() == [] and store.get_plan(plan.id).result == done.result

    def test_transitions_and_records_are_checked(self, plan_backend):
        store = plan_backend.open()
        plan, _ = store.create_plan(SCENE)
        with pytest.raises(IllegalTransitionError):
            store.finish(plan.id, {})
        with pytest.raises(InvalidRecordError, match="while it runs"):
            store.record_material(plan.id, "x", {})
        store.start(plan.id, 1)
        with pytest.raises(InvalidRecordError, match="not strict JSON"):
            store.record_material(plan.id, "x", {"error": float("nan")})
        failed = store.fail(plan.id, "no such file")
        assert failed.status is PlanStatus.FAILED and failed.error == "no such file"
        with pytest.raises(IllegalTransitionError):
            store.start(plan.id, 1)
        with pytest.raises(NotFoundError, match="no plan 'nope'"):
            store.get_plan("nope")

    def test_idempotency_keys_and_owners(self, plan_backend):
        store = plan_backend.open()
        a, created = store.create_plan(SCENE, owner="ana", idempotency_key="k1")
        b, again = store.create_plan(SCENE, owner="ana", idempotency_key="k1")
        assert created and not again and a.id == b.id
        with pytest.raises(ConflictError, match="k1"):
            store.create_plan({**SCENE, "ladder": ["ward"]}, owner="ana", idempotency_key="k1")
        bos, created = store.create_plan({**SCENE, "ladder": ["ward"]}, owner="bo", idempotency_key="k1")
        assert created and bos.id != a.id  # keys are per owner: ana's plan is not named to bo
        assert [p.owner for p in store.list_plans()] == ["bo", "ana"]
        assert [p.id for p in store.list_plans(owner="ana")] == [a.id]

    def test_a_plan_is_cancelled_once_and_a_finished_one_keeps_its_files(self, plan_backend):
        store = plan_backend.open()
        queued, _ = store.create_plan(SCENE)
        running, _ = store.create_plan(SCENE)
        store.start(running.id, 1)
        assert [store.cancel(p.id).status for p in (queued, running)] == [PlanStatus.CANCELLED] * 2
        assert store.get_plan(running.id).terminal and store.unfinished_plans() == []
        assert store.cancel(running.id).status is PlanStatus.CANCELLED  # again: the same status, no change
        with pytest.raises(InvalidRecordError, match="while it runs"):
            store.record_material(running.id, "late", {})  # a planner still at work after the cancel
        done, _ = store.create_plan(SCENE)
        store.start(done.id, 0)
        files = {"plan.json": "ab" * 32}
        assert store.finish(done.id, {}, files).files == files == plan_backend.open().get_plan(done.id).files
        with pytest.raises(IllegalTransitionError):
            store.cancel(done.id)

    def test_materials_recorded_from_many_threads_all_arrive(self, plan_backend):
        store = plan_backend.open()
        plan, _ = store.create_plan(SCENE)
        store.start(plan.id, 40)
        threads = [threading.Thread(target=store.record_material, args=(plan.id, f"m{i}", {"i": i})) for i in range(40)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        recorded = store.planned_materials(plan.id)
        assert sorted(recorded) == sorted(f"m{i}" for i in range(40)) and store.get_plan(plan.id).materials_done == 40
