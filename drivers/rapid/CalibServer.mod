MODULE CalibServer
    ! calibd calibration server for IRC5 (RobotWare 6, no paid option needed).
    ! The daemon writes the target through Robot Web Services 1.0
    ! (POST /rw/rapid/symbol/data/RAPID/T_ROB1/<var>?action=set), then calib_cmd,
    ! then bumps calib_seq. This loop executes the command and sets calib_ack := calib_seq.
    ! calib_err: 0 = ok, 1 = unknown command, 2 = target unreachable (error handler).
    ! See drivers/src/rws/driver.rs (RwsHandle::move_abs_j / move_rel_tool).

    PERS jointtarget calib_q := [[0,0,0,0,30,0],[9E9,9E9,9E9,9E9,9E9,9E9]];
    PERS pos calib_dp := [0,0,0];
    PERS num calib_cmd := 0;
    PERS num calib_seq := 0;
    PERS num calib_ack := 0;
    PERS num calib_err := 0;
    PERS tooldata calib_tool := [TRUE,[[0,0,0],[1,0,0,0]],[0.1,[0,0,1],[1,0,0,0],0,0,0]];
    CONST speeddata calib_v := v50;

    PROC main()
        VAR num last;
        last := calib_seq;
        calib_ack := calib_seq;
        WHILE TRUE DO
            IF calib_seq <> last THEN
                last := calib_seq;
                calib_err := 0;
                TEST calib_cmd
                CASE 1:
                    MoveAbsJ calib_q, calib_v, fine, calib_tool;
                CASE 2:
                    MoveL RelTool(CRobT(\Tool:=calib_tool \WObj:=wobj0), calib_dp.x, calib_dp.y, calib_dp.z),
                        calib_v, fine, calib_tool \WObj:=wobj0;
                DEFAULT:
                    calib_err := 1;
                ENDTEST
                calib_ack := last;
            ENDIF
            WaitTime 0.02;
        ENDWHILE
    ERROR
        ! Unreachable target or joint out of range: report and skip the command.
        IF ERRNO = ERR_ROBLIMIT OR ERRNO = ERR_OUTSIDE_REACH THEN
            calib_err := 2;
            calib_ack := last;
            SkipWarn;
            TRYNEXT;
        ENDIF
    ENDPROC
ENDMODULE
