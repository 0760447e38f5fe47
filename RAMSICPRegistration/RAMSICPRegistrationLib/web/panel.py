"""The page: the workflow panel in a side drawer, the Slicer views in the main area (trame Vuetify 3 widgets).

Every value shown comes from the state that ``panel_state`` fills; every button calls a controller action through
the app (``NavigationWebApp.run``) and is disabled, with the reason as its tooltip, when ``availability()`` says
it cannot run. Elements the tests read carry an ``id``.
"""

PANEL_WIDTH_PX = 400


def _view_marker(view):
    """A hidden element beside the view's image, ``id="view-<singleton tag>"`` (ThreeD, Red, Green, Yellow), so
    that a test finds each view's ``<img>``."""
    from trame.widgets import html

    html.Span(id=f"view-{view.get_singleton_tag()}", style="display: none;")


def three_d_view_gutter(server, view_id, view):
    from trame_slicer.app.ui import create_vertical_view_gutter_ui

    create_vertical_view_gutter_ui(server, view_id, view)
    _view_marker(view)


def slice_view_gutter(server, view_id, view):
    from trame_slicer.app.ui import create_vertical_slice_view_gutter_ui

    create_vertical_slice_view_gutter_ui(server, view_id, view)
    _view_marker(view)


def _action_button(app, label, action, icon=None, **options):
    from trame.widgets import vuetify3 as v3

    return v3.VBtn(
        label,
        click=options.pop("click", lambda: app.run(action)),
        disabled=(f"!!blocked.{action} || !!busy",),
        title=(f"blocked.{action}",),
        prepend_icon=icon,
        size="small",
        variant="tonal",
        classes="ma-1",
        **options,
    )


def _vector_readout(label, key, element_id):
    """'label: (x, y, z) mm' from a state list of three texts, shown only when there is one."""
    from trame.widgets import html

    html.Div(f"{label}: ({{{{ {key}.join(', ') }}}}) mm", v_if=f"{key}.length", id=element_id, classes="text-body-2")


def _choice(app, label, name, items, **options):
    """A select bound to a parameter of the node (``method``, ``policy``): the page shows it, a change writes it."""
    from trame.widgets import vuetify3 as v3

    v3.VSelect(
        label=label,
        items=(items,),
        model_value=(name,),
        update_modelValue=(lambda value: app.set_choice(name, value), "[$event]"),
        density="compact",
        hide_details=True,
        id=name,
        **options,
    )


def _section(title):
    from trame.widgets import vuetify3 as v3

    card = v3.VCard(variant="flat", classes="mb-2")
    with card:
        v3.VCardSubtitle(title, classes="pt-2 text-uppercase font-weight-bold")
    return card


def build_page(app):
    """Build the page's UI on ``app.server`` (a NavigationWebApp)."""
    from trame.widgets import html
    from trame.widgets import vuetify3 as v3
    from trame_vuetify.ui.vuetify3 import SinglePageWithDrawerLayout

    with SinglePageWithDrawerLayout(app.server, full_height=True) as page:
        page.title.set_text("RAMSICP Navigator")
        page.footer.hide()
        with page.toolbar:
            v3.VSpacer()
            html.Div(
                "{{ message }}",
                id="message",
                classes=("message_is_error ? 'text-error text-body-2 px-4' : 'text-body-2 px-4'",),
            )
            v3.VProgressCircular(v_if="busy", indeterminate=True, size=20, classes="mr-4")
        page.drawer.width = PANEL_WIDTH_PX
        page.drawer.permanent = True
        with page.drawer, html.Div(classes="pa-2", style="overflow-y: auto; height: 100%;"):
            _tracker_section()  # the live readouts first: what the surgeon glances at
            _pivot_section(app)
            _collect_section(app)
            _register_section(app)
            _next_touch_section(app)
            _checkpoint_section(app)
            _cut_section(app)
            _save_section(app)
        with page.content:
            app.layout.initialize_layout_grid(page)
    return page


def _tracker_section():
    from trame.widgets import html
    from trame.widgets import vuetify3 as v3

    with _section("Tracker"), v3.VCardText(classes="py-1"):
        html.Div("{{ connection }}", id="connection", classes="text-body-2 mb-1")
        v3.VChip(
            "{{ tool.name }}: {{ tool.state }}",
            v_for="tool in tools",
            key="tool.name",
            id=("'tool-' + tool.name",),
            color=("tool.colour",),
            size="small",
            classes="ma-1",
            variant="flat",
        )
        html.Div("tip to bone surface (verify)", classes="text-body-2 mt-2")
        html.Div(
            "{{ tip_to_surface ? tip_to_surface + ' mm' : '-' }}",
            id="tip-to-surface",
            style="font-size: 44px; font-weight: 700; line-height: 1.1;",
        )


def _pivot_section(app):
    from trame.widgets import html
    from trame.widgets import vuetify3 as v3

    with _section("Probe tip (pivot)"), v3.VCardText(classes="py-1"):
        _action_button(app, "Start pivot", "start_pivot", "mdi-record")
        _action_button(app, "Stop pivot", "stop_pivot", "mdi-stop")
        html.Div("recording: {{ pivot_poses }} poses", v_if="pivot_recording", id="pivot-poses", classes="text-body-2")
        _vector_readout("tip offset (probe frame)", "tip_offset", "tip-offset")


def _collect_section(app):
    from trame.widgets import html
    from trame.widgets import vuetify3 as v3

    with _section("Patient points"), v3.VCardText(classes="py-1"):
        _action_button(app, "Collect point", "collect_point", "mdi-map-marker-plus")
        _action_button(app, "Reference body markers", "add_reference_body_markers", "mdi-target")
        v3.VSwitch(
            label=("`auto-collect every ${auto_collect_mm} mm`",),
            model_value=("auto_collect",),
            update_modelValue=(lambda value: app.run("set_auto_collect", bool(value)), "[$event]"),
            disabled=("!auto_collect && (!!blocked.set_auto_collect || !!busy)",),
            density="compact",
            hide_details=True,
            color="primary",
            id="auto-collect",
        )
        html.Div(
            "probe points: <b id='probe-points'>{{ probe_points }}</b>, marker centres: "
            "<b id='marker-points'>{{ marker_points }}</b>",
            classes="text-body-2",
        )
        _vector_readout("tip (reference frame)", "tip_reference", "tip-reference")


def _register_section(app):
    from trame.widgets import html
    from trame.widgets import vuetify3 as v3

    with _section("Registration"), v3.VCardText(classes="py-1"):
        with v3.VRow(dense=True):
            with v3.VCol(cols=6):
                _choice(app, "method", "method", "methods")
            with v3.VCol(cols=6):
                _choice(app, "L policy", "policy", "policies", disabled=("method !== 'cr-ramsicp'",))
        _action_button(app, "Register", "register", "mdi-vector-link", click=app.register)
        with html.Div(v_if="registered", classes="text-body-2"):
            html.Div("FRE <b id='fre'>{{ fre }}</b> mm, TRE <b id='tre'>{{ tre || '-' }}</b> mm")
            html.Div("probe points {{ ppc_rms }} mm RMS from the bone<span v-if='scale'>, L = {{ scale }}</span>")
        with v3.VAlert(v_if="alarms.length", type="error", density="compact", classes="my-1", id="alarms"):
            html.Div(
                "ALARM: this registration is not used for navigation until you accept it.", classes="font-weight-bold"
            )
            html.Div("{{ alarm }}", v_for="alarm in alarms", classes="text-body-2 my-1")
            _action_button(app, "Accept registration", "accept_registration", "mdi-alert")
        with v3.VAlert(v_if="warnings.length", type="warning", density="compact", classes="my-1", id="warnings"):
            html.Div("{{ warning }}", v_for="warning in warnings", classes="text-body-2 my-1")
        html.Div(v_html=("sweep_svg",), id="sweep", classes="my-1")
        with v3.VTable(v_if="residuals.length", density="compact", height=220, fixed_header=True, id="residuals"):
            with html.Thead(), html.Tr():
                html.Th("point")
                html.Th("residual (mm)")
                html.Th("include")
                html.Th("note")
            with (
                html.Tbody(),
                html.Tr(v_for="row in residuals", key="row.index", classes=("row.note ? 'text-error far-point' : ''",)),
            ):
                html.Td("{{ row.label }}")
                html.Td("{{ row.residual }}")
                with html.Td():
                    v3.VCheckboxBtn(
                        model_value=("row.include",),
                        update_modelValue=(app.set_included, "[row.index, $event]"),
                        density="compact",
                        hide_details=True,
                    )
                html.Td("{{ row.note }}")


def _number(label, name, element_id, **options):
    """A number field bound to the page's own state ``name`` (what the user types stays until a button sends it)."""
    from trame.widgets import vuetify3 as v3

    v3.VTextField(
        label=label,
        v_model=(name,),
        type="number",
        density="compact",
        hide_details=True,
        id=element_id,
        **options,
    )


def _next_touch_section(app):
    """Issue 26: where to touch next (drawn on the bone as an orange sphere), the predicted error it would bring,
    'enough' against the plan's limit, and guided collection that takes only touches near the drawn point."""
    from trame.widgets import html
    from trame.widgets import vuetify3 as v3

    with _section("Next touch"), v3.VCardText(classes="py-1"):
        v3.VTextField(
            label="error allowed at the plan's targets (mm)",
            model_value=("target_tre",),
            update_modelValue=(app.set_target_tre, "[$event]"),
            type="number",
            step=0.05,
            density="compact",
            hide_details=True,
            id="target-tre",
        )
        with v3.VAlert(
            v_if="next_touch",
            type=("next_touch && next_touch.enough ? 'success' : 'info'",),
            density="compact",
            classes="my-1",
            id="next-touch",
        ):
            html.Div(
                "<b v-if='next_touch.enough'>ENOUGH touches</b><span v-else>next touch: the orange point "
                "on the bone, it brings <b id='next-touch-after'>{{ next_touch.after }}</b> mm</span>",
            )
            html.Div(
                "predicted error now <b id='next-touch-now'>{{ next_touch.now }}</b> mm (95 % bound "
                "{{ next_touch.bound }} mm)<span v-if='next_touch.tip_distance'>; tip {{ next_touch.tip_distance }} mm "
                "from the point</span>",
                classes="text-body-2",
            )
        html.Div("{{ next_touch_text }}", v_if="!next_touch && next_touch_text", classes="text-body-2")
        v3.VSwitch(
            label="follow the suggestions (hold still on the point, lift; registers after each)",
            model_value=("guided_collect",),
            update_modelValue=(lambda value: app.run("set_guided_collect", bool(value)), "[$event]"),
            disabled=("!guided_collect && (!!blocked.set_guided_collect || !!busy)",),
            title=("blocked.set_guided_collect",),
            density="compact",
            hide_details=True,
            color="primary",
            id="guided-collect",
        )


def _checkpoint_section(app):
    """Issue 26: checkpoints on the bone stored after the registration and touched again later; one that moved
    beyond the limit is an alarm (the reference body slipped)."""
    from trame.widgets import html
    from trame.widgets import vuetify3 as v3

    with _section("Checkpoints"), v3.VCardText(classes="py-1"):
        _action_button(app, "Store checkpoint", "store_checkpoint", "mdi-map-marker-check")
        _action_button(app, "Check checkpoint", "check_checkpoint", "mdi-map-marker-question")
        html.Div(
            "stored: <b id='checkpoint-count'>{{ checkpoint_count }}</b>"
            "<span v-if='checkpoint_text'> &mdash; <span id='checkpoint-text'>{{ checkpoint_text }}</span></span>",
            classes="text-body-2",
        )
        with v3.VAlert(v_if="checkpoint_alarm", type="error", density="compact", classes="my-1", id="checkpoint-alarm"):
            html.Div("{{ checkpoint_alarm }}", classes="text-body-2 font-weight-bold", style="white-space: pre-line;")


def _plane_inputs(app):
    """The osteotomy plane placed by numbers in the bone's frame, or through the tracked tip on the bone."""
    from trame.widgets import html
    from trame.widgets import vuetify3 as v3

    with v3.VRow(dense=True):
        for label, name, element_id in (
            ("level below the top (mm)", "plane_level", "plane-level"),
            ("tilt anterior (deg)", "plane_tilt_anterior", "plane-tilt-anterior"),
            ("tilt to the side (deg)", "plane_tilt_side", "plane-tilt-side"),
            ("blade enters at (deg)", "plane_entry", "plane-entry"),
        ):
            with v3.VCol(cols=6):
                _number(label, name, element_id)
    _action_button(
        app,
        "Place the plane",
        "place_osteotomy_plane",
        "mdi-knife",
        click=(app.place_plane, "[plane_level, plane_tilt_anterior, plane_tilt_side, plane_entry]"),
    )
    _action_button(
        app, "Plane through the tip", "place_plane_at_tip", "mdi-crosshairs-gps", click=app.place_plane_at_tip
    )
    html.Div(
        "plane: {{ plane.level }} mm below the top, tilted {{ plane.tilt_anterior }}&deg; anterior and "
        "{{ plane.tilt_side }}&deg; to the side, blade entering at {{ plane.entry }}&deg;",
        v_if="plane",
        id="plane",
        classes="text-body-2",
    )


def _cut_section(app):
    """The osteotomy plan and the live guidance of the tracked cutting tool: the plane is placed here (by numbers in
    the bone's frame, or through the tip) or comes with the scene; the page plans on it, sends the path to the
    robot and shows how the tool lies."""
    from trame.widgets import html
    from trame.widgets import vuetify3 as v3

    with _section("Plan and cut"), v3.VCardText(classes="py-1"):
        _plane_inputs(app)
        _action_button(app, "Plan the cut", "plan_cut", "mdi-vector-line")
        _action_button(app, "Send the path to the robot", "send_tool_path", "mdi-robot-industrial")
        _action_button(app, "Stop the robot", "stop_robot", "mdi-hand-back-left", color="error")
        html.Div("{{ cut }}", v_if="cut", id="cut", classes="text-body-2")
        html.Div(
            "{{ robot }}<span v-if='robot_progress.length'> ({{ robot_progress[0] }} of {{ robot_progress[1] }} "
            "poses)</span>",
            v_if="robot",
            id="robot",
            classes="text-body-2",
        )
        with html.Div(
            v_if="guidance",
            id="guidance",
            classes=("guidance && guidance.on_plan ? 'bg-success pa-2 mt-1 rounded' : 'bg-error pa-2 mt-1 rounded'",),
        ):
            html.Div(
                "{{ guidance.distance }} mm &nbsp; {{ guidance.angle }}&deg;",
                style="font-size: 34px; font-weight: 700; line-height: 1.1;",
            )
            html.Div("{{ guidance.text }}", classes="text-body-2")


def _save_section(app):
    from trame.widgets import vuetify3 as v3

    with _section("Save"), v3.VCardText(classes="py-1"):
        _action_button(app, "Save scene", "save", "mdi-content-save", click=app.save)
