MODULE PickPlace
    !***********************************************************
    ! Module:  PickPlace
    ! Cell:    IRB 120 pick-and-place with glue dispense
    ! Author:  line 3 integration, rev C
    !
    ! Picks parts from the infeed fixture, dispenses a glue bead
    ! around the part on the glue station and places it in the
    ! outfeed tray (3 x 2 pockets).
    !***********************************************************

    ! --- Tools -------------------------------------------------
    PERS tooldata tGripper:=[TRUE,[[0,0,115.5],[1,0,0,0]],[0.85,[0,0,48],[1,0,0,0],0,0,0]];
    PERS tooldata tGlue:=[TRUE,[[32.1,0,142.7],[0.965925826,0,0.258819045,0]],
                          [0.6,[10,0,60],[1,0,0,0],0,0,0]];

    ! --- Work objects ------------------------------------------
    TASK PERS wobjdata wInfeed:=[FALSE,TRUE,"",[[350,-180,20],[1,0,0,0]],[[0,0,0],[1,0,0,0]]];
    TASK PERS wobjdata wTray:=[FALSE,TRUE,"",[[260,210,15],[0.996194698,0,0,0.087155743]],
                               [[5,-3,0],[1,0,0,0]]];

    ! --- Speeds and zones --------------------------------------
    CONST speeddata vApproach:=[400,200,5000,1000];
    CONST zonedata zPass:=[FALSE,2,3,3,0.3,3,0.3];
    VAR num nPart:=0;
    VAR bool bGlueOk:=TRUE;

    ! --- Positions ---------------------------------------------
    CONST robtarget pHome:=[[374,0,630],[0.5,0,0.866025404,0],[0,0,0,0],[9E+09,9E+09,9E+09,9E+09,9E+09,9E+09]];
    CONST robtarget pPick:=[[12.5,8,35],[0,0,1,0],[-1,0,-1,0],[9E+09,9E+09,9E+09,9E+09,9E+09,9E+09]];
    ! Glue bead: four corners of the part, dispense nozzle tilted 30 deg
    CONST robtarget pGlue{4}:=[
        [[380.25,-40,180],[0.258819045,0,0.965925826,0],[-1,-1,0,1],[9E+09,9E+09,9E+09,9E+09,9E+09,9E+09]],
        [[380.25,40,180],[0.258819045,0,0.965925826,0],[0,0,-1,1],[9E+09,9E+09,9E+09,9E+09,9E+09,9E+09]],
        [[440.75,40,180],[0.258819045,0,0.965925826,0],[0,0,-1,1],[9E+09,9E+09,9E+09,9E+09,9E+09,9E+09]],
        [[440.75,-40,180],[0.258819045,0,0.965925826,0],[-1,-1,0,1],[9E+09,9E+09,9E+09,9E+09,9E+09,9E+09]]];
    ! Tray pockets, 3 columns x 2 rows (row-major)
    PERS robtarget pTray{2,3}:=[[[[0,0,40],[0,0,1,0],[0,0,0,0],[9E+09,9E+09,9E+09,9E+09,9E+09,9E+09]],
                                 [[60,0,40],[0,0,1,0],[0,0,0,0],[9E+09,9E+09,9E+09,9E+09,9E+09,9E+09]],
                                 [[120,0,40],[0,0,1,0],[0,0,0,0],[9E+09,9E+09,9E+09,9E+09,9E+09,9E+09]]],
                                [[[0,55,40],[0,0,1,0],[0,0,0,0],[9E+09,9E+09,9E+09,9E+09,9E+09,9E+09]],
                                 [[60,55,40],[0,0,1,0],[0,0,0,0],[9E+09,9E+09,9E+09,9E+09,9E+09,9E+09]],
                                 [[120,55,40],[0,0,1,0],[0,0,0,0],[9E+09,9E+09,9E+09,9E+09,9E+09,9E+09]]]];
    VAR robtarget pCurrent;

    PROC main()
        ! Cycle: pick, glue, place
        MoveJ pHome, v1000, z50, tGripper;
        FOR i FROM 1 TO 6 DO
            PickPart;
            IF bGlueOk THEN
                Glue;
            ELSE
                TPWrite "glue skipped for part "\Num:=nPart;
            ENDIF
            PlacePart (i - 1) DIV 3 + 1, (i - 1) MOD 3 + 1;
        ENDFOR
        MoveJ pHome, v1000, fine, tGripper;
    ENDPROC

    PROC PickPart()
        MoveJ Offs(pPick,0,0,80), vApproach, zPass, tGripper\WObj:=wInfeed;
        MoveL pPick, v100, fine, tGripper\WObj:=wInfeed;
        WaitTime 0.2;   ! gripper closes
        MoveL Offs(pPick,0,0,80), v200, z10, tGripper\WObj:=wInfeed;
        nPart := nPart + 1;
    ENDPROC

    PROC Glue()
        MoveJ RelTool(pGlue{1},0,0,-30), vApproach, z10, tGlue;
        MoveL pGlue{1}, v50, fine, tGlue;
        MoveL pGlue{2}, v40\V:=45, z1, tGlue;
        MoveC pGlue{3}, pGlue{4}, v40, z1, tGlue;
        MoveL pGlue{1}, v40, fine, tGlue;
        MoveL RelTool(pGlue{1},0,0,-30), v200, z10, tGlue;
    ERROR
        IF ERRNO = ERR_PATH_STOP THEN
            StartMove;
            RETRY;
        ENDIF
    ENDPROC

    PROC PlacePart(num row, num col)
        MoveJ Offs(pTray{row,col},0,0,60), vApproach, zPass, tGripper\WObj:=wTray;
        MoveL pTray{row,col}, v100, fine, tGripper\WObj:=wTray;
        WaitTime 0.2;   ! gripper opens
        MoveL Offs(pTray{row,col},0,0,60), v200, z10, tGripper\WObj:=wTray;
        TEST col
        CASE 1, 2:
            pCurrent := CRobT(\Tool:=tGripper\WObj:=wTray);
        DEFAULT:
            TPWrite "row done";
        ENDTEST
    ENDPROC
ENDMODULE
